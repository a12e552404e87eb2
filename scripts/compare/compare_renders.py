#!/usr/bin/python3
"""Compares two `spar render` output folders of one request (PSNR, masks, label maps).

Compares two `spar render` output folders of the same request: the lowest PSNR over the
rendered views (view_*.png, 8-bit), whether the motion masks (mask_*.png) and label maps
(labels_*.png) are identical, and the largest camera difference (cameras.json).

    compare_renders.py REFERENCE OTHER [--min-psnr DB]

Prints one line; exits 1 when a view is below --min-psnr (default 40 dB) or a mask differs."""
import argparse
import glob
import json
import math
import os
import sys

import numpy as np
from PIL import Image


def load(path):
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64)


def psnr(a, b):
    mse = float(np.mean((a - b) ** 2))
    return math.inf if mse == 0 else 10 * math.log10(255.0 ** 2 / mse)


def cameras(d):
    with open(os.path.join(d, "cameras.json")) as f:
        doc = json.load(f)
    values = []

    def walk(x):
        if isinstance(x, (int, float)) and not isinstance(x, bool):
            values.append(float(x))
        elif isinstance(x, dict):
            for k in sorted(x):
                walk(x[k])
        elif isinstance(x, list):
            for v in x:
                walk(v)
    walk(doc)
    return np.array(values)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("reference")
    ap.add_argument("other")
    ap.add_argument("--min-psnr", type=float, default=40.0)
    a = ap.parse_args(argv)
    views = sorted(os.path.basename(p) for p in glob.glob(os.path.join(a.reference, "view_*.png")))
    if not views:
        print(f"compare_renders: no view_*.png in {a.reference}", file=sys.stderr)
        return 2
    worst = min(psnr(load(os.path.join(a.reference, v)), load(os.path.join(a.other, v))) for v in views)
    def same(pattern):
        names = sorted(os.path.basename(p) for p in glob.glob(os.path.join(a.reference, pattern)))
        return all(np.array_equal(load(os.path.join(a.reference, n)), load(os.path.join(a.other, n))) for n in names), len(names)
    masks_same, masks = same("mask_*.png")
    labels_same, labels = same("labels_*.png")
    ca, cb = cameras(a.reference), cameras(a.other)
    cam = float(np.max(np.abs(ca - cb))) if ca.shape == cb.shape else math.inf
    print(f"{len(views)} views: lowest PSNR {worst:.1f} dB; {masks} masks {'identical' if masks_same else 'DIFFER'}; "
          f"{labels} label maps {'identical' if labels_same else 'differ'}; cameras max abs diff {cam:.2e}")
    return 0 if worst >= a.min_psnr and masks_same else 1


if __name__ == "__main__":
    sys.exit(main())
