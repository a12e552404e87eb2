#!/usr/bin/python3
"""Goldens of tests/test_sam2_hiera_block.cpp: one Hiera block of SAM2.1
(spar_reference.sam2.hiera_block) in float64 on float32 weights and inputs, per case:

    OUT/<case>/x.npy [H, W, dim] f32, y.npy [H', W', dim_out] f64, spec.json, and every weight
    as <official name>.npy f32 (norm1.weight.npy, attn.qkv.weight.npy, ...)

Cases cross what the block's layout does: windows padded at the bottom and right (10 -> 12
with window 4: the edge windows hold bias-only pad keys), an odd window (3, 7 -> 9), a
q-pooling transition inside padded windows (10 -> 12, windows of 6 pooled to 3, the pooled
grid 6 cropped to 5), a global block, and a global q-pooling block."""
import argparse
import json
import os

import numpy as np
import torch

from spar_reference import sam2

# name: (H, W, dim, dim_out, heads, window, q_pool)
CASES = {
    "padded_windows": (10, 10, 8, 8, 2, 4, False),
    "odd_window": (7, 9, 4, 4, 1, 3, False),
    "q_pool_padded": (10, 10, 8, 16, 2, 6, True),
    "global": (6, 5, 8, 8, 2, 0, False),
    "global_q_pool": (8, 6, 4, 8, 2, 0, True),
    # the official hiera_t / hiera_s windows on their maps: 14 on 64x64 (padded to 70, the
    # last row and column of windows 8 of 14 tokens real), 7 on 32x32 (padded to 35)
    "window_14_on_64": (64, 64, 8, 8, 2, 14, False),
    "window_7_on_32": (32, 32, 8, 8, 2, 7, False),
    # stiff: a global block whose attention logits reach about 1e3 (q and k scaled), and one
    # whose input rows have mean 1e4 (its LayerNorm, eps 1e-6, as LayerNorm2d's)
    "global_logits_1e3": (8, 8, 8, 8, 2, 0, False),
    "rows_of_mean_1e4": (6, 7, 8, 8, 2, 3, False),
}
# q and k of the qkv projection scaled by this (logits by its square: ~1e3)
LOGIT_SCALE = {"global_logits_1e3": 20.0}
INPUT_OFFSET = {"rows_of_mean_1e4": 1e4}


def weights(dim, dim_out, g):
    shapes = {"norm1.weight": (dim,), "norm1.bias": (dim,), "attn.qkv.weight": (3 * dim_out, dim),
              "attn.qkv.bias": (3 * dim_out,), "attn.proj.weight": (dim_out, dim_out), "attn.proj.bias": (dim_out,),
              "norm2.weight": (dim_out,), "norm2.bias": (dim_out,), "mlp.layers.0.weight": (4 * dim_out, dim_out),
              "mlp.layers.0.bias": (4 * dim_out,), "mlp.layers.1.weight": (dim_out, 4 * dim_out),
              "mlp.layers.1.bias": (dim_out,)}
    if dim != dim_out:
        shapes.update({"proj.weight": (dim_out, dim), "proj.bias": (dim_out,)})
    out = {}
    for k, s in shapes.items():
        t = torch.randn(*s, generator=g)
        out[k] = (1.0 + 0.2 * t if k.startswith("norm") and k.endswith("weight") else
                  0.5 * t if len(s) == 1 else t / np.sqrt(s[1]))
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    for i, (name, (h, w, dim, dim_out, heads, window, q_pool)) in enumerate(sorted(CASES.items())):
        d = os.path.join(args.out, name)
        os.makedirs(d, exist_ok=True)
        g = torch.Generator().manual_seed(100 + i)
        wt = weights(dim, dim_out, g)
        if name in LOGIT_SCALE:
            wt["attn.qkv.weight"][:2 * dim_out] *= LOGIT_SCALE[name]
            wt["attn.qkv.bias"][:2 * dim_out] *= LOGIT_SCALE[name]
        x = torch.randn(1, h, w, dim, generator=g) + INPUT_OFFSET.get(name, 0.0)
        sd = {"b." + k: v.to(torch.float64) for k, v in wt.items()}
        blk = dict(dim=dim, dim_out=dim_out, heads=heads, window=window, q_pool=int(q_pool))
        with torch.no_grad():
            y = sam2.hiera_block(x.to(torch.float64), sd, "b.", blk)[0]
        np.save(os.path.join(d, "x.npy"), x[0].numpy().astype(np.float32))
        np.save(os.path.join(d, "y.npy"), y.numpy())
        for k, v in wt.items():
            np.save(os.path.join(d, k + ".npy"), v.numpy().astype(np.float32))
        with open(os.path.join(d, "spec.json"), "w") as f:
            json.dump(dict(blk, height=h, width=w), f)


if __name__ == "__main__":
    main()
