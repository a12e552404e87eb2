#!/usr/bin/python3
"""Compares two `spar render` output folders of one request (PSNR, masks, label maps).

Compares two `spar render` output folders of the same request: the lowest PSNR over the
rendered views (view_*.png, 8-bit), whether the motion masks (mask_*.png) and label maps
(labels_*.png) are identical (else the share of their pixels that agree), and the largest camera
difference (cameras.json).

    compare_renders.py REFERENCE OTHER [--min-psnr DB] [--min-mask-agreement F] [--min-label-agreement F]

Prints one line; exits 1 when a view is below --min-psnr (default 40 dB), when fewer mask pixels
agree than --min-mask-agreement (default 1: any difference), or fewer label pixels than
--min-label-agreement (default 0: label maps do not gate)."""
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
    ap.add_argument("--min-mask-agreement", type=float, default=1.0)
    ap.add_argument("--min-label-agreement", type=float, default=0.0)
    a = ap.parse_args(argv)
    views = sorted(os.path.basename(p) for p in glob.glob(os.path.join(a.reference, "view_*.png")))
    if not views:
        print(f"compare_renders: no view_*.png in {a.reference}", file=sys.stderr)
        return 2
    worst = min(psnr(load(os.path.join(a.reference, v)), load(os.path.join(a.other, v))) for v in views)
    def agreement(pattern):
        """(share of pixels equal in every file, file count); a pixel agrees when all channels do."""
        names = sorted(os.path.basename(p) for p in glob.glob(os.path.join(a.reference, pattern)))
        equal = total = 0
        for n in names:
            x, y = load(os.path.join(a.reference, n)), load(os.path.join(a.other, n))
            equal += int(np.all(x == y, axis=-1).sum())
            total += x.shape[0] * x.shape[1]
        return (equal / total if total else 1.0), len(names)

    def said(share, what):
        return "identical" if share == 1.0 else f"{100 * share:.2f} % of pixels equal" + (" (DIFFER)" if what else "")
    mask_share, masks = agreement("mask_*.png")
    label_share, labels = agreement("labels_*.png")
    ca, cb = cameras(a.reference), cameras(a.other)
    cam = float(np.max(np.abs(ca - cb))) if ca.shape == cb.shape else math.inf
    print(f"{len(views)} views: lowest PSNR {worst:.1f} dB; {masks} masks {said(mask_share, a.min_mask_agreement == 1)}; "
          f"{labels} label maps {said(label_share, False)}; cameras max abs diff {cam:.2e}")
    ok = worst >= a.min_psnr and mask_share >= a.min_mask_agreement and label_share >= a.min_label_agreement
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
