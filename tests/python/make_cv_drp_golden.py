#!/usr/bin/python3
"""Goldens for tests/test_cv_drp.cpp that the model-level fixture does not have, from the
PyTorch reference (reference/spar_reference/spar.py) in float64:

    make_cv_drp_golden.py pairs OUT.json
        get_view_pairs(v, mode) for v = 1..6, modes input and target: {"input": [[[i, j], ...], ...], ...}

    make_cv_drp_golden.py identical GOLDENS_DIR OUT_DIR
        All views identical: view 0's dino / img / ray tokens of GOLDENS_DIR/interleaved repeated
        to 5 views (tokens.{dino,img,ray}.npy [5, n, D]), CV-DRP of the tiny model
        (GOLDENS_DIR/tiny.pt) over all 5 as inputs and as targets, and over view 0 alone:
        <input|target|single>.<logits|prob|pair_logits>.npy.
"""
import json
import os
import sys
import types

import numpy as np


import torch  # noqa: E402

from spar_reference.cli import load_checkpoint  # noqa: E402
from spar_reference.config import SparConfig  # noqa: E402
from spar_reference.spar import SPAR, CrossViewDynamicRegionPredictor, get_view_pairs  # noqa: E402


def pairs(out):
    table = {m: [[list(p) for p in get_view_pairs(v, m)] for v in range(1, 7)] for m in ("input", "target")}
    with open(out, "w") as f:
        json.dump(table, f)


def identical(goldens, out):
    torch.set_num_threads(1)  # fixtures run beside another test (ctest -j2)
    os.makedirs(out, exist_ok=True)
    cfg = SparConfig.from_file(os.path.join(goldens, "tiny_photometric.json"))
    sd = load_checkpoint(os.path.join(goldens, "tiny.pt"))
    prefix = "cv_drp."
    cv = CrossViewDynamicRegionPredictor(cfg)
    cv.load_state_dict({k[len(prefix):]: v for k, v in sd.items() if k.startswith(prefix)}, strict=True)
    cv = cv.double().eval()
    # run_cv_drp reads only .cfg and .cv_drp of the model
    host = types.SimpleNamespace(cfg=cfg, cv_drp=cv)
    views = 5
    toks = {}
    for name, key in (("dino", "dino"), ("img", "img_tokens"), ("ray", "ray_tokens")):
        a = np.load(os.path.join(goldens, "interleaved", key + ".npy"))[0, 0]  # [n, D] of view 0
        toks[name] = torch.from_numpy(np.ascontiguousarray(np.broadcast_to(a, (views,) + a.shape)))
        np.save(os.path.join(out, "tokens.%s.npy" % name), toks[name].numpy())
    with torch.no_grad():
        for case, mode, count in (("input", "input", views), ("target", "target", views), ("single", "input", 1)):
            sub = [toks[k][:count][None] for k in ("dino", "img", "ray")]
            r = SPAR.run_cv_drp(host, *sub, mode)
            for key in ("logits", "prob", "pair_logits"):
                np.save(os.path.join(out, "%s.%s.npy" % (case, key)), r[key].numpy())


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "pairs":
        pairs(sys.argv[2])
    elif len(sys.argv) == 4 and sys.argv[1] == "identical":
        identical(sys.argv[2], sys.argv[3])
    else:
        sys.exit(__doc__)
