#!/usr/bin/python3
"""Times the official-size model on the engine beside the PyTorch reference, stage by stage.

Full-size wall time and peak memory: the engine (`spar render`) next to the PyTorch reference
(`spar-reference render`, float32, 2 threads) on the same inputs, stage by stage, plus the error
of the engine's renders against the reference's (with and without --assume-static).

    scripts/compare/compare_full.py [--out build/compare-full] [--spar build/bin/spar] [--cases 2x1,4x4]

Makes (once) the official configuration without the semantic branch with random perturbed
weights (seed 11; about 1.4 GB as .pt and again as .spar under --out), eight procedural frames,
and runs:
    2x1: frames 0..2, inputs 0,2, target 1           (issue: 2 inputs + 1 target at 256x256)
    4x4: frames 0..7, inputs 0,2,4,6, targets 1,3,5,7
Peak memory is the maximum resident set size (/usr/bin/time -v): for lavapipe it includes the
device memory, which lives in host memory. Run it on an otherwise idle machine.
"""
import argparse
import json
import os
import re
import shutil
import subprocess
import sys

import numpy as np
from PIL import Image

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# The repository's Python roots this program imports from, found from here (nothing installed).
sys.path[:0] = [os.path.join(ROOT, d) for d in ("reference", "converter", os.path.join("tests", "python"))]

from spar_convert.model_config import full  # noqa: E402
from make_spar_goldens import frames  # noqa: E402
from spar_reference.cli import ENGINE_STAGE_MAP as STAGE_MAP  # noqa: E402



def timed(cmd, env=None):
    """Runs cmd under /usr/bin/time -v; returns peak RSS in MB."""
    r = subprocess.run(["/usr/bin/time", "-v", *cmd], capture_output=True, text=True,
                       env=dict(os.environ, **(env or {})))
    if r.returncode != 0:
        sys.stderr.write(r.stderr[-3000:])
        raise SystemExit(f"failed: {' '.join(cmd)}")
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr)
    return int(m.group(1)) / 1024.0


def psnr(a, b):
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


def views(d):
    return [np.asarray(Image.open(os.path.join(d, f))) for f in sorted(os.listdir(d))
            if f.startswith("view_")]


def masks(d):
    return [np.asarray(Image.open(os.path.join(d, f))) for f in sorted(os.listdir(d))
            if f.startswith("mask_")]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=os.path.join(ROOT, "build", "compare-full"))
    ap.add_argument("--spar", default=os.path.join(ROOT, "build", "bin", "spar"))
    ap.add_argument("--cases", default="2x1,4x4")
    args = ap.parse_args()
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    cfg_path = os.path.join(out, "full_photometric.json")
    ck, packed = os.path.join(out, "full.pt"), os.path.join(out, "full.spar")
    if not os.path.exists(packed):
        cfg = full()
        cfg.use_lseg = False
        with open(cfg_path, "w") as f:
            json.dump(cfg.validate().to_dict(), f, indent=1)
        ref = os.path.join(ROOT, "reference", "spar-reference")
        subprocess.run([sys.executable, ref, "make-checkpoint", "--config", cfg_path, "--seed", "11",
                        "--perturb", "--no-optimizer", "-o", ck], check=True)
        subprocess.run([sys.executable, os.path.join(ROOT, "converter", "spar-convert"), "-q", ck, "--config",
                        cfg_path, "-o", packed], check=True)
    f = frames(out, count=8, width=320, height=240)
    cases = {"2x1": (f[:3], "0,2"), "4x4": (f, "0,2,4,6")}
    rows = []
    for name in args.cases.split(","):
        files, inputs = cases[name]
        res = {}
        for tag, cmd in [
            ("engine", [args.spar, "render", "--model", packed]),
            ("engine_static", [args.spar, "render", "--model", packed, "--assume-static"]),
            ("reference", [sys.executable, os.path.join(ROOT, "reference", "spar-reference"), "render",
                           "--checkpoint", ck, "--config", cfg_path]),
            ("reference_static", [sys.executable, os.path.join(ROOT, "reference", "spar-reference"), "render",
                                  "--checkpoint", ck, "--config", cfg_path, "--assume-static"]),
        ]:
            d = os.path.join(out, f"{name}_{tag}")
            shutil.rmtree(d, ignore_errors=True)
            rss = timed([*cmd, "--frames", *files, "--inputs", inputs, "--out", d])
            with open(os.path.join(d, "report.json")) as fh:
                rep = json.load(fh)
            res[tag] = (d, rss, rep)
        rows.append((name, res))

    for name, res in rows:
        e, ref = res["engine"][2], res["reference"][2]
        es = {s["name"]: s["wall_ms"] / 1000 for s in e["stages"]}
        egpu = {s["name"]: s["gpu_ms"] / 1000 for s in e["stages"]}
        es["renderer"] = es.get("renderer", 0) + es.get("render_rays", 0)
        egpu["renderer"] = egpu.get("renderer", 0) + egpu.get("render_rays", 0)
        rs = {s["name"]: s["seconds"] for s in ref["stages"]}
        print(f"\n### {name}: {e['views']['inputs']} inputs, {e['views']['targets']} targets, 256x256\n")
        print("| stage | engine wall s | engine GPU s | reference s | engine / reference |")
        print("|---|---|---|---|---|")
        for stage, refs in STAGE_MAP:
            r = sum(rs.get(x, 0.0) for x in refs)
            w = es.get(stage, 0.0)
            if not r and not w:  # a stage neither ran (e.g. LSeg of a model without it)
                continue
            print(f"| {stage} | {w:.2f} | {egpu.get(stage, 0.0):.2f} | {r:.2f} | {w / r if r else 0:.2f} |")
        print(f"| **total (process)** | {e['total_seconds']:.2f} | | {ref['total_seconds']:.2f} | "
              f"{e['total_seconds'] / ref['total_seconds']:.2f} |")
        print(f"\npeak RSS: engine {res['engine'][1]:.0f} MB, reference {res['reference'][1]:.0f} MB; "
              f"--assume-static: engine {res['engine_static'][2]['total_seconds']:.2f} s "
              f"({res['engine_static'][1]:.0f} MB), reference "
              f"{res['reference_static'][2]['total_seconds']:.2f} s")
        ev, rv = views(res["engine"][0]), views(res["reference"][0])
        sv, rsv = views(res["engine_static"][0]), views(res["reference_static"][0])
        p = [psnr(a, b) for a, b in zip(ev, rv)]
        ps = [psnr(a, b) for a, b in zip(sv, rsv)]
        pd = [psnr(a, b) for a, b in zip(sv, rv)]
        md = max(int(np.abs(a.astype(int) - b.astype(int)).max()) for a, b in zip(ev, rv))
        em, rm = masks(res["engine"][0]), masks(res["reference"][0])
        agree = np.mean([np.mean(a == b) for a, b in zip(em, rm)]) * 100
        print(f"engine vs reference renders (8-bit PNGs): PSNR min {min(p):.1f} dB, max |diff| {md}/255, "
              f"mask agreement {agree:.3f}%; with --assume-static on both: PSNR min {min(ps):.1f} dB; "
              f"--assume-static engine vs full reference: PSNR min {min(pd):.1f} dB (the effect of "
              f"leaving CV-DRP out on this scene)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
