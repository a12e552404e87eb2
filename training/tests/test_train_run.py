#!/usr/bin/python3
"""``spar-train``'s run options for a GPU run (issue 14): held-out measurement during training
(--eval-scenes), a time budget (--minutes), --device, --image-size, --scene-tokens.

Cheap by construction: 32x32 scenes (the smallest size the recipe accepts), three scenes, a few
steps, one thread. One run trains the teacher (module fixture `base`); the others reuse it with
--teacher and share its scene cache. Runs and one-line errors go through spar_train.cli.main in
this process; the --minutes run is a real `spar-train` subprocess (the entry script, the real
clock). The time budget's arithmetic is tested with a fake clock (TimeBudget(clock=...)).
Run: cd /work/main && /usr/bin/python3 -m pytest -q training/tests/test_train_run.py
"""

import json
import os
import subprocess
import sys

import pytest
import torch

HERE = os.path.dirname(os.path.abspath(__file__))

from spar_train import cli  # noqa: E402
from spar_train.time_budget import CALIBRATION_STEPS, OVERRUN, WARMUP_STEPS, TimeBudget  # noqa: E402

TOOL = os.path.join(HERE, "..", "spar-train")
SIZE = "32"


def args(out, *extra, cache, teacher=None):
    a = ["--out", str(out), "--scenes", "3", "--image-size", SIZE, "--lseg-steps", "2",
         "--threads", "1", "--workers", "1", "--save-every", "0", "--log-every", "1", "--no-pack",
         "--cache", str(cache)]
    if teacher:
        a += ["--teacher", str(teacher)]
    return a + [str(x) for x in extra]


def train_in_process(argv, capsys):
    """spar_train.cli.main(argv) here: (return code, stdout, stderr). The thread count the run
    sets is put back afterwards."""
    threads = torch.get_num_threads()
    try:
        code = cli.main(argv)
    finally:
        torch.set_num_threads(threads)
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def val_scenes(tmp_path_factory):
    d = tmp_path_factory.mktemp("val") / "scenes"
    subprocess.run([sys.executable, os.path.join(HERE, "..", "..", "scenes", "spar-scenes"), "split", "--split",
                    "test", "--count", "1", "--start", "12", "--size", SIZE, "--out", str(d)],
                   check=True, capture_output=True)
    return d


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A plain 3-step run that trains the teacher and renders the scene pool (shared)."""
    d = tmp_path_factory.mktemp("train")
    cache = d / "cache"
    threads = torch.get_num_threads()
    try:
        assert cli.main(args(d / "plain", "--steps", "3", cache=cache)) == 0
    finally:
        torch.set_num_threads(threads)
    return {"dir": d, "cache": cache, "run": d / "plain", "teacher": d / "plain" / "teacher.pt"}


def weights(run):
    return torch.load(os.path.join(run, "checkpoint.pt"))["model"]


def test_measuring_held_out_scenes_changes_no_weight(base, val_scenes, capsys):
    """The held-out measurement runs the model in eval mode between steps: it must leave the
    training exactly as it was (same seed: the same weights bit for bit). Both runs use the
    teacher the plain run trained (the measured one loads it)."""
    out = base["dir"] / "measured"
    code, so, se = train_in_process(args(out, "--steps", "3", "--eval-scenes", val_scenes,
                                         "--eval-every", "2", cache=base["cache"],
                                         teacher=base["teacher"]), capsys)
    assert code == 0, se
    a, b = weights(base["run"]), weights(out)
    assert list(a) == list(b)
    for k in a:
        assert torch.equal(a[k], b[k]), k
    curve = [json.loads(line) for line in open(out / "curve.jsonl")]
    # before training, every --eval-every steps and the last step
    assert [c["step"] for c in curve] == [0, 2, 3]
    for c in curve:
        assert c["views"] == 3
        for key in ("psnr", "ssim", "psnr_nearest_input", "psnr_mean_colour", "sem_miou",
                    "mask_miou"):
            assert c[key] is not None and c[key] == c[key], key
        assert 5.0 < c["psnr"] < 60.0
    # the baselines do not depend on the model
    assert len({c["psnr_nearest_input"] for c in curve}) == 1
    assert "held-out step 3" in so and "copy" in so


# ----------------------------------------------------------------------------- time budget
class FakeClock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self):
        return self.now


def simulate(minutes, max_steps, step_seconds, eval_every=0, eval_seconds=0.0):
    """The loop of spar_train.train.Run.train with a fake clock: a held-out measurement before
    the first step, every `eval_every` steps and after the last; the budget consulted before
    each step, the overrun after it. step_seconds(step) is the time of step `step` (0-based)."""
    clock, logs, evals = FakeClock(), [], []
    budget = TimeBudget(minutes, max_steps, eval_every or 250, log=logs.append, clock=clock)
    calls = []

    def measure():
        evals.append(eval_seconds)
        clock.now += eval_seconds

    if eval_every:
        measure()
    total, step, cut = max_steps, 0, False
    while step < total:
        before = total
        total = budget.steps(step, total, sum(evals), len(evals))
        calls.append((step, before, total))
        clock.now += step_seconds(step)
        step += 1
        if eval_every and (step % eval_every == 0 or step == total):
            measure()
        if budget.overrun() and step < total:
            cut = True
            break
    return {"steps": step, "total": total, "logs": logs, "calls": calls, "cut": cut,
            "elapsed": clock.now - 1000.0, "budget": budget}


def calibrated_at(r):
    changed = [s for s, before, after in r["calls"] if after != before]
    return changed[0] if changed else None


def test_time_budget_off_is_exactly_steps():
    r = simulate(0, 40, lambda s: 100.0)
    assert r["steps"] == 40 and r["total"] == 40 and not r["cut"] and r["logs"] == []
    assert all(after == 40 for _, _, after in r["calls"])
    assert not r["budget"].overrun()      # 4000 s later: no budget, no overrun


def test_time_budget_calibrates_after_warmup_and_timed_steps():
    """A long budget: the rate is measured over CALIBRATION_STEPS steps after WARMUP_STEPS
    (whose slowness does not count), and the schedule filled to the budget."""
    r = simulate(10, 100000, lambda s: 10.0 if s < WARMUP_STEPS else 1.0)
    at = WARMUP_STEPS + CALIBRATION_STEPS
    assert calibrated_at(r) == at
    assert all(after == 100000 for s, _, after in r["calls"] if s < at)
    spent = WARMUP_STEPS * 10.0 + CALIBRATION_STEPS * 1.0
    assert r["total"] == at + int(600 - spent)
    assert r["logs"] == [f"time budget 10 min: 1.000 s a step, 0.0 s a held-out measurement "
                         f"-> {r['total']} steps"]
    assert r["steps"] == r["total"] and not r["cut"]
    assert r["elapsed"] == pytest.approx(600.0)


def test_time_budget_short_budget_calibrates_after_two_timed_steps():
    """Once a fifth of the budget is gone, two timed steps after the warm-up are enough (and
    fewer are never used, however late it is)."""
    r = simulate(0.1, 100000, lambda s: 0.5)
    assert calibrated_at(r) == WARMUP_STEPS + 2
    assert r["total"] == WARMUP_STEPS + 2 + int((6.0 - 3.5) / 0.5)
    assert r["steps"] == r["total"] and r["elapsed"] == pytest.approx(6.0) and not r["cut"]
    # past the fifth already during the warm-up: still WARMUP_STEPS + 2 steps before deciding
    r = simulate(0.1, 100000, lambda s: 0.7)
    assert calibrated_at(r) == WARMUP_STEPS + 2


def test_time_budget_charges_held_out_measurements_per_step():
    """Measurement time is not training time: it is left out of the step rate and charged at
    the rate measurements recur (per_eval / eval_every a step)."""
    r = simulate(10, 100000, lambda s: 1.0, eval_every=10, eval_seconds=5.0)
    at = WARMUP_STEPS + CALIBRATION_STEPS
    assert calibrated_at(r) == at
    elapsed = at * 1.0 + 3 * 5.0          # measurements at steps 0, 10 and 20
    assert r["total"] == at + int((600 - elapsed) / (1.0 + 5.0 / 10))
    assert r["logs"][0].endswith(f"1.000 s a step, 5.0 s a held-out measurement -> {r['total']} steps")
    assert r["steps"] == r["total"] and not r["cut"]
    assert 600 * 0.97 < r["elapsed"] <= 600 * OVERRUN


def test_time_budget_caps_and_floors():
    # never more than --steps
    r = simulate(10, 100, lambda s: 1.0)
    assert r["total"] == 100 and r["steps"] == 100
    # a budget already spent at calibration: one more step, not fewer than done
    r = simulate(0.05, 100000, lambda s: 0.4 if s < WARMUP_STEPS + 2 else 100.0)
    assert calibrated_at(r) == WARMUP_STEPS + 2
    assert r["total"] == WARMUP_STEPS + 3 and r["steps"] == WARMUP_STEPS + 3 and not r["cut"]


def test_time_budget_overrun_cuts_the_schedule_short():
    """Steps that slow down after calibration: the run stops once it is OVERRUN past its
    budget, before the schedule's end; the overrun is strict (exactly 1.1 x is not over)."""
    r = simulate(1, 100000, lambda s: 1.0 if s < 30 else 10.0)
    assert r["cut"] and r["steps"] < r["total"]
    assert 60 * OVERRUN < r["elapsed"] <= 60 * OVERRUN + 10.0
    clock = FakeClock()
    b = TimeBudget(1, 100, 250, log=lambda s: None, clock=clock)
    clock.now += 60 * OVERRUN
    assert not b.overrun()
    clock.now += 1e-6
    assert b.overrun()


def test_time_budget_fits_the_schedule(base, val_scenes):
    """The real thing, end to end in a subprocess (the entry script, the real clock): --minutes:
    the step rate is measured after the first steps and the schedule's length set from it; the
    run stops near the budget, with its last step measured and saved. A 15 s budget: the 7
    steps before calibration (and the first measurement) take about 1 s on an idle machine, but
    up to 1.4 s each beside a memory-heavy test under ctest -j2 (measured: 3 steps in 5 s, and a
    4.2 s budget overran before calibrating), so they still calibrate before the overrun stops
    the run."""
    minutes = 0.25
    p = subprocess.run([sys.executable, TOOL] + args(
        base["dir"] / "budget", "--batch", "1", "--steps", "100000", "--minutes", minutes,
        "--eval-scenes", val_scenes, "--eval-every", "10", cache=base["cache"],
        teacher=base["teacher"]), capture_output=True, text=True, timeout=900)
    assert p.returncode == 0, p.stderr
    assert f"time budget {minutes} min" in p.stdout
    total = int(p.stdout.split(f"time budget {minutes} min")[1].split("->")[1].split()[0])
    assert 5 < total < 100000
    ck = torch.load(base["dir"] / "budget" / "checkpoint.pt")
    steps = ck["param_update_step"]
    assert min(total, 8) <= steps <= total   # calibrated after at least 5 + 2 steps
    curve = [json.loads(line) for line in open(base["dir"] / "budget" / "curve.jsonl")]
    assert curve[-1]["step"] == steps
    assert curve[-1]["minutes"] < minutes * 1.1 + 0.2
    # a checkpoint written on any device holds CPU tensors (spar-convert reads those only)
    assert all(v.device.type == "cpu" for v in ck["model"].values())


def test_scene_tokens_size_the_latent(base, capsys):
    """--scene-tokens N: the scene latent (scene_code) has N rows, config.json says so, and the
    converter packs it against that config (the GPU variant with 192 tokens goes this way)."""
    from spar_convert.convert import main as convert_main
    run = base["dir"] / "tokens"
    code, _, se = train_in_process(args(run, "--steps", "1", "--scene-tokens", "24",
                                        cache=base["cache"], teacher=base["teacher"]), capsys)
    assert code == 0, se
    assert tuple(weights(run)["scene_code"].shape) == (24, 128)
    assert json.load(open(run / "config.json"))["scene_tokens"] == 24
    packed = base["dir"] / "m.spar"
    code = convert_main(["-q", str(run / "checkpoint.pt"), "--config", str(run / "config.json"),
                         "-o", str(packed)])
    assert code == 0 and packed.stat().st_size > 0, capsys.readouterr().err


@pytest.mark.parametrize("extra, message", [
    (["--device", "cuda:99"], "CUDA device"),   # no CUDA here; on a GPU machine: no 100th GPU
    (["--device", "tpu"], "--device tpu"),
    (["--image-size", "40"], "multiple of 16"),
    (["--minutes", "-1"], "--minutes"),
    (["--scene-tokens", "0"], "--scene-tokens"),
    (["--eval-scenes", "/nonexistent/scenes"], "not a directory"),
    (["--init-from", "/nonexistent/m.spar"], "--init-from /nonexistent/m.spar: no such file"),
    (["--init-from", os.path.join(HERE, "..", "..", "data", "spar_rooms.spar"), "--scene-tokens", "24"],
     "another configuration"),
])
def test_bad_options_are_one_line_errors(tmp_path, extra, message, capsys):
    code, _, se = train_in_process(args(tmp_path / "run", "--steps", "1", *extra,
                                        cache=tmp_path / "cache"), capsys)
    assert code != 0
    lines = [line for line in se.strip().splitlines() if line]
    assert len(lines) == 1 and message in lines[0], se
    assert "Traceback" not in se
    assert not (tmp_path / "run" / "checkpoint.pt").exists()
