#!/usr/bin/env python3
"""Times PyTorch on the GPU check's op shapes and model: what the engine is compared with there.

The PyTorch side of scripts/gpu/gpu-check.sh: on the same GPU, what the engine is compared with.

    gpu_reference_bench.py --ops --out ops.json [--device cuda] [--repeat 10] [--small]
    gpu_reference_bench.py --checkpoint full.pt --config full.json --out model.json
                           [--views 4] [--targets 4] [--size 256x256] [--semantic] [--repeat 5]

--ops: torch.matmul of 4096 x 4096 x 4096 in fp32 with TF32 off and in fp16 (cuBLAS), and
scaled_dot_product_attention with 12 heads of 64 over 1280 and 2816 tokens in fp32 and fp16 (the
engine's spar-bench cases), each the median of CUDA-event timings after warm-up. --small
shrinks the shapes (a check of this script on a CPU).
--checkpoint: SPAR's PyTorch reference (reference/spar_reference) on spar-bench --model's
synthetic frames (tools/spar_bench/bench_model.h: the same hash, so the same inputs), V inputs then T
targets, the targets rendered with their estimated cameras, in fp32 eager and with the model and
frames in bfloat16: per stage (module hooks with CUDA events, the stage names of spar-reference's
report) and in total, median of --repeat runs after one warm-up run.
Run with the python3 that has PyTorch (on the GPU machine; Debian's /usr/bin/python3 here).
"""
import argparse
import json
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# The repository's Python roots this program imports from, found from here (nothing installed).
sys.path[:0] = [os.path.join(ROOT, d) for d in ("reference", "converter")]


def synthetic_images(views, h, w):
    """tools/spar_bench/bench_model.cpp syntheticImages: murmur3's finalizer of the element index."""
    i = np.arange(views * 3 * h * w, dtype=np.uint64)
    x = ((i + np.uint64((0x9E3779B9 * 12345) & 0xFFFFFFFF)) & np.uint64(0xFFFFFFFF)).astype(np.uint32)
    x ^= x >> np.uint32(16)
    x = (x.astype(np.uint64) * np.uint64(0x85EBCA6B) & np.uint64(0xFFFFFFFF)).astype(np.uint32)
    x ^= x >> np.uint32(13)
    x = (x.astype(np.uint64) * np.uint64(0xC2B2AE35) & np.uint64(0xFFFFFFFF)).astype(np.uint32)
    x ^= x >> np.uint32(16)
    return ((x >> np.uint32(8)).astype(np.float32) / np.float32(16777216.0)).reshape(views, 3, h, w)


class Timer:
    """Elapsed time of a callable: CUDA events on a GPU, perf_counter on a CPU."""

    def __init__(self, torch, device):
        self.torch, self.cuda = torch, device.startswith("cuda")

    def once(self, fn):
        """ms of one call of fn, its work finished."""
        torch = self.torch
        if self.cuda:
            a, b = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            a.record()
            fn()
            b.record()
            torch.cuda.synchronize()
            return a.elapsed_time(b)
        t = time.perf_counter()
        fn()
        return (time.perf_counter() - t) * 1e3

    def __call__(self, fn, repeat):
        """Median ms of repeat calls after a warm-up call (kernels chosen, caches filled)."""
        self.once(fn)
        return float(np.median([self.once(fn) for _ in range(repeat)]))


def measured(run, entry, flops):
    """entry with the median ms and GFLOPS of run(), or the error it raised (e.g. no fp16
    matrix product on a CPU): one case that cannot run does not stop the others."""
    try:
        ms = run()
    except RuntimeError as e:
        return dict(entry, error=str(e).splitlines()[0])
    return dict(entry, ms=ms, gflops=flops / (ms * 1e6))


def bench_ops(args, torch):
    dev = args.device
    timer = Timer(torch, dev)
    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False
    n = 1024 if args.small else 4096  # --small: spar-bench's 1024^3 case, seconds on a CPU
    out = []
    for dtype, name in ((torch.float32, "gemm_f32"), (torch.float16, "gemm_f16")):
        a = torch.randn(n, n, device=dev, dtype=dtype)
        b = torch.randn(n, n, device=dev, dtype=dtype)
        lib = "torch.matmul (cuBLAS), TF32 off" if dev.startswith("cuda") else "torch.matmul"
        out.append(measured(lambda: timer(lambda: torch.matmul(a, b), args.repeat),
                            {"name": name, "shape": f"{n}x{n}x{n}", "library": lib}, 2.0 * n ** 3))
    heads, dh = 12, 64
    # PyTorch's fused attention (FlashAttention / memory-efficient kernels on CUDA); PyTorch
    # before 2.0 (Debian 12's) has none: the plain softmax(q k^T / sqrt(d)) v then.
    f = getattr(torch.nn.functional, "scaled_dot_product_attention", None)
    library = "torch.nn.functional.scaled_dot_product_attention"
    if f is None:
        library = "softmax(q k^T / 8) v (this PyTorch has no scaled_dot_product_attention)"
        f = lambda q, k, v: torch.softmax(q @ k.transpose(-1, -2) / 8.0, dim=-1) @ v  # noqa: E731
    for tokens in ((1280,) if args.small else (1280, 2816)):
        for dtype, name in ((torch.float32, "attention_f32"), (torch.float16, "attention_f16")):
            q, k, v = (torch.randn(1, heads, tokens, dh, device=dev, dtype=dtype) for _ in range(3))
            out.append(measured(lambda: timer(lambda: f(q, k, v), args.repeat),
                                {"name": name, "shape": f"{heads}x{dh} heads, {tokens} tokens",
                                 "library": library},
                                4.0 * tokens * tokens * dh * heads))
    return out


# What the PyTorch peer computes in each mode (spar-bench's model rows are compared with these).
MATH = {
    "fp32": "fp32; TF32 off for matmul and cuDNN",
    "bf16": "bf16 weights and activations (model.to(torch.bfloat16)); autocast fails on the reference's mixed-type "
            "Pluecker ops",
}
# The reference's attention: the official modules' own softmax(q k^T / sqrt(d)) v in torch.matmul,
# not scaled_dot_product_attention (as the official code writes it).
ATTENTION = "explicit softmax(q k^T / sqrt(d)) v (torch.matmul), as the official modules compute it"


def bench_model(args, torch):
    from spar_reference.cli import MODEL_STAGES, build_model, get_config, load_checkpoint, split_state_dict
    dev = args.device
    sd = load_checkpoint(args.checkpoint)
    cfg = get_config(args.config, sd, args.checkpoint)
    model_sd, _ = split_state_dict(sd)
    model = build_model(cfg, model_sd, False).to(dev)
    h, w = cfg.image_height, cfg.image_width
    if args.size:
        h, w = (int(x) for x in args.size.split("x"))
    v = args.views + args.targets
    x = torch.from_numpy(synthetic_images(v, h, w))[None].to(dev)
    inputs, targets = list(range(args.views)), list(range(args.views, v))
    cuda = dev.startswith("cuda")
    timer = Timer(torch, dev)
    # fp32 is fp32: no TF32 in matmuls or convolutions (PyTorch allows it in cuDNN by default)
    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False

    # Per stage: CUDA events around every hooked module call, summed after the run.
    events = {}
    handles = []

    def hook(module, stage):
        def pre(m, inp):
            if cuda:
                e = torch.cuda.Event(enable_timing=True)
                e.record()
            else:
                e = time.perf_counter()
            events.setdefault(stage, []).append([e, None])

        def post(m, inp, outp):
            if cuda:
                e = torch.cuda.Event(enable_timing=True)
                e.record()
            else:
                e = time.perf_counter()
            events[stage][-1][1] = e
        handles.append(module.register_forward_pre_hook(pre))
        handles.append(module.register_forward_hook(post))

    import torch.nn as nn
    for stage, attrs in MODEL_STAGES:
        for a in attrs:
            mod = getattr(model, a, None)
            for m in (mod if isinstance(mod, nn.ModuleList) else [mod] if isinstance(mod, nn.Module) else []):
                hook(m, stage)

    def stage_ms():
        if cuda:
            torch.cuda.synchronize()
        return {s: sum((a.elapsed_time(b) if cuda else (b - a) * 1e3) for a, b in pairs)
                for s, pairs in events.items()}

    def run(m, frames):
        with torch.no_grad():
            out = m(frames, inputs, targets, render=False)
            m.render(out, semantic_head=args.semantic)

    results = {}
    for mode in ("fp32", "bf16"):
        # bf16: the model's weights and the frames in bfloat16 (autocast leaves some of the
        # reference's mixed-type ops, e.g. the Pluecker cross product, failing)
        if mode == "bf16":
            model = model.to(torch.bfloat16)
        frames = x.to(torch.bfloat16) if mode == "bf16" else x

        def once():
            run(model, frames)
        events.clear()
        t = time.perf_counter()
        try:
            once()
        except RuntimeError as e:  # recorded, not fatal: the other mode's numbers still count
            results[mode] = {"error": str(e).splitlines()[0]}
            print(f"gpu_reference_bench: {mode} failed: {results[mode]['error']}", file=sys.stderr)
            continue
        if cuda:
            torch.cuda.synchronize()
        first = (time.perf_counter() - t) * 1e3
        totals, stages = [], {}
        for _ in range(args.repeat):
            events.clear()
            totals.append(timer.once(once))
            for s, ms in stage_ms().items():
                stages.setdefault(s, []).append(ms)
        results[mode] = {"math": MATH[mode], "first_run_ms": first, "total_ms": float(np.median(totals)),
                         "stages": {s: float(np.median(v)) for s, v in stages.items()}}
    for hd in handles:
        hd.remove()
    return {"checkpoint": args.checkpoint, "inputs": args.views, "targets": args.targets, "height": h, "width": w,
            "semantic": bool(args.semantic), "repeat": args.repeat, "attention": ATTENTION, "modes": results}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--ops", action="store_true")
    p.add_argument("--small", action="store_true", help="small shapes (a check of the script on a CPU)")
    p.add_argument("--checkpoint")
    p.add_argument("--config")
    p.add_argument("--views", type=int, default=4)
    p.add_argument("--targets", type=int, default=4)
    p.add_argument("--size", help="HxW (default: the model's)")
    p.add_argument("--semantic", action="store_true", help="also the semantic head")
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--device", default=None, help="default: cuda when available, else cpu")
    p.add_argument("--threads", type=int, default=0, help="CPU threads (0: PyTorch's default)")
    p.add_argument("--out", required=True)
    a = p.parse_args(argv)
    if not a.ops and not a.checkpoint:
        p.error("--ops or --checkpoint")
    import torch
    if a.threads:
        torch.set_num_threads(a.threads)
    a.device = a.device or ("cuda" if torch.cuda.is_available() else "cpu")
    doc = {"tool": "gpu_reference_bench.py", "torch": torch.__version__, "device": a.device,
           "device_name": torch.cuda.get_device_name(0) if a.device.startswith("cuda") else "cpu"}
    if a.ops:
        doc["ops"] = bench_ops(a, torch)
    if a.checkpoint:
        doc["model"] = bench_model(a, torch)
    with open(a.out, "w") as f:
        json.dump(doc, f, indent=1)
    print(json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
