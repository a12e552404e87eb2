#!/usr/bin/python3
"""Goldens for tests/test_dino_v3.cpp beyond the spar_goldens cases: the reference DINOv3
(reference/spar_reference/dino_v3.py, SPAR's DINOv3FeatureExtractor) in float64, with the
tiny checkpoint's weights (``_dino_v3.*``), on images the pipeline goldens do not have.

    make_dino_golden.py --checkpoint tiny.pt --config tiny_photometric.json --out DIR

writes one directory per case, images.npy [V,3,H,W] '<f4' (the engine's input values) and
dino.npy [V,n,E] '<f8' (the reference run in float64 on exactly those values):
    black_white   V=2, 128x128: all 0 and all 1 (constant images: every patch the same)
    nonsquare     V=2, 80x112 (5x7 patches): uniform random in [0, 1] (rows != columns)
"""
import argparse
import os
import sys

import numpy as np
import torch

from spar_convert.model_config import SparConfig  # noqa: E402
from spar_reference.cli import load_checkpoint  # noqa: E402
from spar_reference.dino_v3 import DinoV3  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--config", required=True)
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)  # fixtures run beside another test (ctest -j2)

    cfg = SparConfig.from_file(args.config)
    sd = load_checkpoint(args.checkpoint)
    prefix = "_dino_v3."
    dino = DinoV3(cfg.dino, device="meta").to_empty(device="cpu")
    dino.load_state_dict({k[len(prefix):]: v for k, v in sd.items() if k.startswith(prefix)}, strict=True)
    dino = dino.double().eval()

    g = torch.Generator().manual_seed(5)
    cases = {
        "black_white": torch.stack([torch.zeros(3, 128, 128), torch.ones(3, 128, 128)]),
        "nonsquare": torch.rand(2, 3, 80, 112, generator=g),
    }
    for name, images in cases.items():
        d = os.path.join(args.out, name)
        os.makedirs(d, exist_ok=True)
        images = images.to(torch.float32)
        with torch.no_grad():
            tokens = dino(images.to(torch.float64))
        np.save(os.path.join(d, "images.npy"), images.numpy().astype("<f4"))
        np.save(os.path.join(d, "dino.npy"), tokens.numpy().astype("<f8"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
