#!/usr/bin/python3
"""SAM2.1 refinement per view: the engine (import spar) beside the PyTorch reference on this CPU.

    PYTHONPATH=build/python:$(bash scripts/setup/pythonpath.sh) /usr/bin/python3 \
        scripts/compare/sam2_refine_bench.py --variant sam2.1_hiera_t [--views 2] [--out result.json]

Makes a random official-layout checkpoint of the variant (spar-reference make-sam2-checkpoint's
code, seed 1), packs it with the tiny SPAR of the tests (reference make-checkpoint --config tiny,
128x128), and refines the same views with the same prompts (a block of dynamic pixels per view,
so every view runs SAM2) three ways: the engine with fp32 weights, with fp16 weights, and the
reference in float32 (torch.set_num_threads(2); OpenBLAS as Debian's torch finds it). Prints and
writes per way: ms per view (the engine's stage "sam2_refine" GPU time and the wall time of the
encode call minus the same call without refinement; the reference's wall time), and against
the reference: differing mask pixels, the largest IoU-score difference, the chosen masks.
Random weights: the masks mean nothing, the agreement and the times do.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
import torch

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--variant", default="sam2.1_hiera_t")
    ap.add_argument("--views", type=int, default=2)
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    import spar
    from spar_convert.model_config import tiny
    from spar_convert.sam2_config import read_sam2_config
    from spar_reference import sam2

    torch.set_num_threads(2)
    work = tempfile.mkdtemp(prefix="sam2-bench-")
    cfg = tiny()
    cfg.use_lseg = False
    cfg_path = os.path.join(work, "tiny.json")
    with open(cfg_path, "w") as f:
        json.dump(cfg.validate().to_dict(), f)
    py = sys.executable
    subprocess.run([py, os.path.join(ROOT, "reference", "spar-reference"), "make-checkpoint", "--config", cfg_path,
                    "--seed", "7", "--no-optimizer", "-o", os.path.join(work, "tiny.pt")], check=True)
    scfg = read_sam2_config(args.variant)
    ck = sam2.make_checkpoint(scfg, seed=1)
    torch.save(ck, os.path.join(work, "sam2.pt"))
    packed = os.path.join(work, "model.spar")
    subprocess.run([py, os.path.join(ROOT, "converter", "spar-convert"), "-q", os.path.join(work, "tiny.pt"),
                    "--config", cfg_path, "--sam2", os.path.join(work, "sam2.pt"), "--sam2-config", args.variant,
                    "-o", packed], check=True)

    v, side = args.views + 1, 128  # the views to refine are the inputs; one more view is the target
    rng = np.random.default_rng(3)
    images = rng.random((v, 3, side, side), dtype=np.float32)
    prompts = np.full((v, side, side), 0.1, np.float32)
    for j in range(v):
        prompts[j, 20 + 10 * j:70 + 10 * j, 30:90] = 0.9
    inputs = list(range(args.views))
    rows = {}
    model = spar.Model.open(packed)
    ctx = spar.Context()
    for precision in ("fp32", "fp16"):
        with spar.Session(ctx, model, fp16_weights=precision == "fp16") as s:
            s.encode(images, inputs=inputs)  # kernels of the rest built once
            s.encode(images, inputs=inputs, refine=True, refine_prompts=prompts)  # SAM2's kernels built
            t0 = time.perf_counter()
            s.encode(images, inputs=inputs)
            plain = time.perf_counter() - t0
            before = {t["name"]: t["gpu_ms"] for t in s.stage_times()}
            t0 = time.perf_counter()
            e = s.encode(images, inputs=inputs, refine=True, refine_prompts=prompts)
            wall = time.perf_counter() - t0 - plain
            gpu = next(t["gpu_ms"] for t in s.stage_times() if t["name"] == "sam2_refine") - before.get("sam2_refine", 0)
        rows[precision] = {"ms_per_view_wall": 1000 * wall / args.views, "ms_per_view_gpu": gpu / args.views,
                           "masks": e["refined_input"], "views": e["refine_views"]}

    t0 = time.perf_counter()
    ref = sam2.refine_masks(ck["model"], scfg, torch.from_numpy(images[inputs]), torch.from_numpy(prompts[inputs]),
                            torch.float32)
    ref_ms = 1000 * (time.perf_counter() - t0) / args.views
    ref_masks = np.stack([r["refined"].numpy() for r in ref])
    result = {"variant": args.variant, "views": args.views, "image": [side, side], "device": ctx.device_name,
              "reference_float32_ms_per_view": ref_ms}
    for precision, r in rows.items():
        iou = max(abs(float(a) - float(b)) for got, want in zip(r["views"], ref) for a, b in zip(got["iou"], want["iou"]))
        result[precision] = {"ms_per_view_wall": r["ms_per_view_wall"], "ms_per_view_gpu": r["ms_per_view_gpu"],
                             "pixels_differing": int((r["masks"] != ref_masks).sum()),
                             "pixels": int(ref_masks.size), "iou_max_abs_diff": iou,
                             "chosen_same": [g["chosen"] == w["chosen"] for g, w in zip(r["views"], ref)]}
    print(json.dumps(result, indent=1))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()
