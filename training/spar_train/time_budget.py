"""spar-train --minutes M: the run's schedule fitted to a time budget. The step rate is unknown
until steps have run (it depends on the device, the batch and, on a shared GPU, the other
processes), so the schedule's length is set once from timed steps: after WARMUP_STEPS (the
allocator's and the first kernels' costs) up to CALIBRATION_STEPS are timed, fewer (at least 2)
once a fifth of a short budget is gone. Time spent on held-out measurements is counted apart
and charged per step at the rate they recur."""
import time

WARMUP_STEPS, CALIBRATION_STEPS = 5, 20
OVERRUN = 1.1   # a run still this far past its budget stops, its schedule cut short


class TimeBudget:
    def __init__(self, minutes: float, max_steps: int, eval_every: int, log=print, clock=time.time):
        # clock: seconds now (time.time; a test passes a fake one)
        self.seconds = minutes * 60.0
        self.minutes, self.max_steps, self.eval_every, self.log = minutes, max_steps, eval_every, log
        self.clock = clock
        self.t0 = clock()
        self.calibrated = not minutes
        self._mark = None   # (time, measurement seconds) after the warm-up

    def steps(self, step: int, total: int, eval_seconds: float, evals_done: int) -> int:
        """Called before each step with the steps done, the schedule's length so far, the
        seconds spent measuring and how many measurements they were: the length to use."""
        if self.calibrated:
            return total
        if step == WARMUP_STEPS:
            self._mark = (self.clock(), eval_seconds)
        timed = step - WARMUP_STEPS
        if self._mark is None or timed < 2 or (timed < CALIBRATION_STEPS and
                                               self.clock() - self.t0 <= 0.2 * self.seconds):
            return total
        per_step = (self.clock() - self._mark[0] - (eval_seconds - self._mark[1])) / timed
        per_eval = eval_seconds / evals_done if evals_done else 0.0
        left = self.seconds - (self.clock() - self.t0)
        total = max(step + 1, min(self.max_steps, step + int(left / (per_step + per_eval / self.eval_every))))
        self.calibrated = True
        self.log(f"time budget {self.minutes} min: {per_step:.3f} s a step, {per_eval:.1f} s a "
                 f"held-out measurement -> {total} steps")
        return total

    def overrun(self) -> bool:
        return bool(self.minutes) and self.clock() - self.t0 > self.seconds * OVERRUN
