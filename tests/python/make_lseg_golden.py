#!/usr/bin/python3
"""Goldens for tests/test_lseg.cpp beyond the spar_goldens_semantic case: the reference LSeg
image encoder (reference/spar_reference/lseg.py) in float64.

    make_lseg_golden.py --checkpoint tiny_semantic.pt --config tiny_semantic.json --out DIR

uses the tiny checkpoint's weights (``lseg_model.*``) and writes one directory per case,
images.npy [V,3,H,W] '<f4' (the engine's input values) and lseg_features.npy
[V,feature_dim,H/2,W/2] '<f8' (the reference run in float64 on exactly those values):
    black_white   V=2, 128x128: all 0 and all 1 (constant images: every patch the same)
    nonsquare     V=2, 96x160 (6x10 tokens; H/32 = 3 is odd): uniform random in [0, 1]
    lseg_norm     V=1, 128x128 random, with input_norm "lseg" ((x - 0.5) / 0.5 first)

    make_lseg_golden.py --full --out DIR

the full-size encoder (ViT-L/16, official sizes) with random perturbed weights (seed 3; the
residual units' convs with their own biases, i.e. use_bn false, what a folded file holds):
DIR/lseg_full.spar, a packed file with only the ``lseg.`` tensors the engine reads, and
DIR/full/{images,lseg_features}.npy for one 256x256 view. Both are kept: a second run with the
same DIR only checks they are there.
"""
import argparse
import json
import os
import sys

import numpy as np
import torch

from spar_convert.model_config import SparConfig, full  # noqa: E402
from spar_convert.safetensors_file import write_safetensors  # noqa: E402
from spar_reference.cli import load_checkpoint  # noqa: E402
from spar_reference.lseg import LSegEncoder, split_lseg_state_dict  # noqa: E402


def save_case(out, name, model, images):
    d = os.path.join(out, name)
    os.makedirs(d, exist_ok=True)
    images = images.to(torch.float32)
    with torch.no_grad():
        feats = model(images.to(torch.float64))
    np.save(os.path.join(d, "images.npy"), images.numpy().astype("<f4"))
    np.save(os.path.join(d, "lseg_features.npy"), feats.numpy().astype("<f8"))


def tiny_cases(args):
    cfg = SparConfig.from_file(args.config)
    sd = load_checkpoint(args.checkpoint)
    prefix = "lseg_model."
    model = LSegEncoder(cfg.lseg, device="meta").to_empty(device="cpu")
    image, _, _ = split_lseg_state_dict({k[len(prefix):]: v for k, v in sd.items() if k.startswith(prefix)})
    model.load_state_dict(image, strict=True)
    model = model.double().eval()

    g = torch.Generator().manual_seed(9)
    save_case(args.out, "black_white", model, torch.stack([torch.zeros(3, 128, 128), torch.ones(3, 128, 128)]))
    save_case(args.out, "nonsquare", model, torch.rand(2, 3, 96, 160, generator=g))
    model.input_norm = "lseg"
    save_case(args.out, "lseg_norm", model, torch.rand(1, 3, 128, 128, generator=g))


# What the converter drops (converter/FORMAT.md): the final norm and the classifier (hooks are
# taken before them), and refinenet4's first residual unit (one input).
def packed(key):
    return not key.startswith(("pretrained.model.norm.", "pretrained.model.head.",
                               "scratch.refinenet4.resConfUnit1."))


def full_case(args):
    path = os.path.join(args.out, "lseg_full.spar")
    case = os.path.join(args.out, "full")
    if os.path.exists(path) and os.path.exists(os.path.join(case, "lseg_features.npy")):
        return
    cfg = full()
    cfg.lseg = dict(cfg.lseg, use_bn=False)
    model = LSegEncoder(cfg.lseg, seed=3, perturb=True).eval()
    hooks_end = max(int(h) for h in cfg.lseg["hooks"]) + 1
    tensors = {}
    for k, v in model.state_dict().items():
        if not packed(k):
            continue
        if k.startswith("pretrained.model.blocks.") and int(k.split(".")[3]) >= hooks_end:
            continue
        tensors["lseg." + k] = v.detach().numpy().astype("<f4")
    meta = {"format": "spar-vulkan", "format_version": "1", "config": json.dumps(cfg.to_dict()),
            "components": json.dumps({"spar": False, "dino": False, "lseg": True, "clip": False, "bpe": False})}
    os.makedirs(args.out, exist_ok=True)
    write_safetensors(path, tensors, meta)
    del tensors
    g = torch.Generator().manual_seed(4)
    save_case(args.out, "full", model.double(), torch.rand(1, 3, 256, 256, generator=g))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--checkpoint")
    ap.add_argument("--config")
    ap.add_argument("--full", action="store_true")
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)  # fixtures run beside another test (ctest -j2)
    if args.full:
        full_case(args)
    else:
        if not args.checkpoint or not args.config:
            ap.error("--checkpoint and --config are required without --full")
        tiny_cases(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
