#!/usr/bin/python3
"""Goldens for tests/test_transformer_block.cpp: two stacked reference ``Block``s in float64.

Builds ``reference/spar_reference/transformer.py``'s Block with the options of one case, every
parameter perturbed away from its init (random norm weights, non-zero biases, LayerScale gammas
of order 1, random QK-norm weights), rounds parameters and input to float32 (so the engine, which
runs in fp32, sees exactly the reference's values), runs the blocks in float64 and writes into
--out:

    blocks.<i>.<official key>.npy   parameters, '<f4' (values of float16 for the weight
                                    matrices of the *_f16w cases)
    x.npy                           input [B, N, D], '<f4'
    y.npy                           output of the 2 blocks [B, N, D], '<f8'
    keys.txt                        one block's state_dict keys, one per line

Usage: make_block_golden.py --case spar|clip|dinov3|spar_f16w --out DIR [--seed S]
"""

import argparse
import os

import numpy as np
import torch

from spar_reference.transformer import Block  # noqa: E402

D, HEAD_DIM, N, B, LAYERS = 64, 32, 37, 2, 2

CASES = {
    # SPAR's stacks: no biases, QK-norm, exact GELU.
    "spar": dict(),
    # CLIP text: LayerNorm and linear biases, QuickGELU, causal mask, no QK-norm.
    "clip": dict(ln_bias=True, qkv_bias=True, fc_bias=True, mlp_bias=True, qk_norm=False,
                 activation="quick_gelu", causal=True),
    # DINOv3: biases, LayerScale, masked k bias, GELU, no QK-norm.
    "dinov3": dict(ln_bias=True, qkv_bias=True, fc_bias=True, mlp_bias=True, qk_norm=False,
                   layerscale=1.0, mask_k_bias=True),
}
# Cases with the weight matrices rounded to float16 (as `spar-convert --fp16` stores them; the
# engine loads them as F16 tensors): the same options as the case named.
FP16_CASES = {"spar_f16w": "spar"}


def perturb(block: Block, gen: torch.Generator, fp16_matrices: bool) -> None:
    with torch.no_grad():
        for name, p in block.named_parameters():
            if name.endswith(".bias"):
                p.copy_(torch.randn(p.shape, generator=gen, dtype=p.dtype) * 0.2)
            elif "norm" in name or name.endswith("gamma"):
                # norm weights and LayerScale: order 1, random, some negative-free spread
                p.copy_(torch.rand(p.shape, generator=gen, dtype=p.dtype) * 1.0 + 0.5)
            else:
                p.copy_((torch.rand(p.shape, generator=gen, dtype=p.dtype) * 2 - 1) / np.sqrt(p.shape[1]) * 1.5)
            storage = torch.float16 if fp16_matrices and p.dim() >= 2 else torch.float32
            p.copy_(p.to(storage).to(torch.float64))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", required=True, choices=sorted(CASES) + sorted(FP16_CASES))
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=1234)
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)

    fp16 = args.case in FP16_CASES
    options = CASES[FP16_CASES.get(args.case, args.case)]
    gen = torch.Generator().manual_seed(args.seed)
    blocks = []
    for i in range(LAYERS):
        blk = Block(D, HEAD_DIM, **options).to(torch.float64).eval()
        perturb(blk, gen, fp16)
        blocks.append(blk)
        for key, value in blk.state_dict().items():
            np.save(os.path.join(args.out, f"blocks.{i}.{key}.npy"), value.numpy().astype("<f4"))

    # Tokens with per-token offsets and scales, so LayerNorm's centring matters.
    x = torch.randn(B, N, D, generator=gen, dtype=torch.float64)
    x = x * (torch.rand(B, N, 1, generator=gen, dtype=torch.float64) * 2 + 0.5) \
        + torch.randn(B, N, 1, generator=gen, dtype=torch.float64) * 2
    x = x.to(torch.float32).to(torch.float64)
    y = x
    with torch.no_grad():
        for blk in blocks:
            y = blk(y)
    np.save(os.path.join(args.out, "x.npy"), x.numpy().astype("<f4"))
    np.save(os.path.join(args.out, "y.npy"), y.numpy().astype("<f8"))
    with open(os.path.join(args.out, "keys.txt"), "w") as f:
        f.write("".join(k + "\n" for k in blocks[0].state_dict()))


if __name__ == "__main__":
    main()
