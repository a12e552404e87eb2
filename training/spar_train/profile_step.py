"""spar-train --profile N: where one training step's time goes (issue 14's throughput lever),
measured on the training recipe itself (same model, batch, losses, optimizer) for N steps
after one warm-up step. The teacher is a fresh LSeg (its weights do not change its cost), so
no teacher is trained. Parts: batch drawing, the frozen LSeg teacher on the clean targets, each
top-level module of SPAR's forward (forward hooks; a module called several times is summed;
time in a module's children is not counted again), the loss, backward, clipping + optimizer.
Prints a table and writes OUT/profile.json."""
import json
import os
import time
from collections import OrderedDict

import torch

from spar_reference import dino_v3, lseg as lseg_mod
from spar_reference.spar import SPAR

from .config import small_config
from .data import ScenePool, Sampler
from .losses import spar_losses


class ModuleTimer:
    """Wall time of each named module's forward calls, exclusive of timed modules inside it
    (several modules may share a name: their times add up)."""

    def __init__(self, modules):
        self.total = OrderedDict((name, 0.0) for name, _ in modules)
        self.stack = []
        self.handles = []
        for name, m in modules:
            self.handles.append(m.register_forward_pre_hook(self._pre(name)))
            self.handles.append(m.register_forward_hook(self._post(name)))

    def _pre(self, name):
        def hook(_module, _inputs):
            self.stack.append([name, time.perf_counter(), 0.0])
        return hook

    def _post(self, name):
        def hook(_module, _inputs, _output):
            n, start, inner = self.stack.pop()
            spent = time.perf_counter() - start
            self.total[n] += spent - inner
            if self.stack:
                self.stack[-1][2] += spent
        return hook

    def reset(self):
        for k in self.total:
            self.total[k] = 0.0


def profile(a) -> int:
    torch.set_num_threads(a.threads)
    torch.manual_seed(a.seed)
    cfg = small_config(a.image_size, a.scene_tokens)
    pool = ScenePool(a.scenes, 8, a.image_size, os.path.join(a.out, "..", "scene-cache")
                     if a.cache is None else a.cache)
    lseg = lseg_mod.LSegEncoder(cfg.lseg, seed=a.seed + 12)
    model = SPAR(cfg, dino=dino_v3.DinoV3(cfg.dino, seed=a.seed + 11), lseg=lseg).float()
    model.train()
    model._dino_v3.eval()
    model.lseg_model.eval()
    named = [(k, p) for k, p in model.named_parameters() if p.requires_grad]
    opt = torch.optim.AdamW([p for _, p in named], lr=a.lr, betas=(0.9, 0.95))
    sampler = Sampler(pool, a.seed)
    # Top-level modules; a ModuleList (the transformer stacks) is timed through its blocks.
    timed = []
    for name, m in model.named_children():
        if name == "lseg_model":
            continue
        timed += [(name, block) for block in m] if isinstance(m, torch.nn.ModuleList) else [(name, m)]
    timer = ModuleTimer(timed)
    parts = OrderedDict()

    def add(name, seconds):
        parts[name] = parts.get(name, 0.0) + seconds

    for step in range(a.profile + 1):      # step 0 warms up (allocations, first-call paths)
        if step == 1:
            parts.clear()
            timer.reset()
        t = time.perf_counter()
        batch = sampler.batch(a.batch)
        add("draw batch", time.perf_counter() - t)
        b, _ = batch["targets"].shape
        ar = torch.arange(b)[:, None]
        t = time.perf_counter()
        with torch.no_grad():
            teacher = model.lseg_model(batch["clean"][ar, batch["targets"]].flatten(0, 1))
        add("LSeg teacher (frozen)", time.perf_counter() - t)
        t = time.perf_counter()
        out = model(batch["images"], batch["inputs"], batch["targets"])
        add("SPAR forward", time.perf_counter() - t)
        t = time.perf_counter()
        losses = spar_losses(out, batch, teacher)
        add("losses", time.perf_counter() - t)
        t = time.perf_counter()
        opt.zero_grad(set_to_none=True)
        losses["loss"].backward()
        add("backward", time.perf_counter() - t)
        t = time.perf_counter()
        torch.nn.utils.clip_grad_norm_([p for _, p in named], 1.0)
        opt.step()
        add("clip + AdamW", time.perf_counter() - t)
    n = a.profile
    step_s = sum(parts.values()) / n
    rows = [(k, v / n) for k, v in parts.items()]
    forward = [(f"  forward: {k}", v / n) for k, v in timer.total.items() if v > 0]
    glue = parts["SPAR forward"] - sum(timer.total.values())
    forward.append(("  forward: outside these modules", glue / n))
    print(f"spar-train --profile: {n} steps of {a.batch} scenes, {a.threads} threads: "
          f"{step_s:.3f} s a step")
    for name, s in rows + forward:
        print(f"  {name:<40s} {s * 1000:9.1f} ms  {100 * s / step_s:5.1f} %")
    doc = {"steps": n, "batch": a.batch, "threads": a.threads, "seconds_per_step": step_s,
           "parts": {k: v for k, v in rows}, "forward_modules": {k: v / n for k, v in timer.total.items()},
           "forward_outside_modules": glue / n}
    os.makedirs(a.out, exist_ok=True)
    with open(os.path.join(a.out, "profile.json"), "w") as f:
        json.dump(doc, f, indent=1)
    return 0
