#!/usr/bin/python3
"""A variant of the spar_goldens tiny model whose motion masks are mixed, for
tests/test_spar_render.cpp: on the fixture's frames the tiny model's CV-DRP logits are nearly
constant (about -0.71 +- 0.002), so P(dynamic) is about 0.33 everywhere and every mask is empty,
which would let a mask comparison pass without comparing anything. Here the CV-DRP head
(cv_drp.estimator.dpt_decoder.head, Conv1x1 16 -> 1) is scaled by GAIN and its bias set so the
mean logit on the fixture's interleaved case is 0: P(dynamic) spreads around 0.5 and the mask
holds both values.

    make_mask_model.py GOLDENS_DIR OUT_DIR

writes OUT_DIR/masked.pt (checkpoint) and OUT_DIR/masked.spar (packed with the fixture's
config, tiny_photometric.json).
"""
import os
import sys

import numpy as np
import torch

HERE = os.path.dirname(os.path.abspath(__file__))
HEAD = "cv_drp.estimator.dpt_decoder.head"
GAIN = 100.0


def make(goldens, out):
    """Writes out/masked.pt and out/masked.spar from the fixture in goldens."""
    from spar_convert.convert import main as convert
    os.makedirs(out, exist_ok=True)
    ck = torch.load(os.path.join(goldens, "tiny.pt"), map_location="cpu")
    sd = ck["model"]
    logits = np.load(os.path.join(goldens, "interleaved", "cv_drp_input.logits.npy"))
    bias = float(sd[HEAD + ".bias"][0])
    # logit = w.x + b  ->  GAIN * w.x + b', with the mean of GAIN * w.x + b' equal to 0
    sd[HEAD + ".weight"] = sd[HEAD + ".weight"] * GAIN
    sd[HEAD + ".bias"] = torch.full_like(sd[HEAD + ".bias"], -GAIN * (float(logits.mean()) - bias))
    pt = os.path.join(out, "masked.pt")
    torch.save(ck, pt)
    if convert(["-q", pt, "--config", os.path.join(goldens, "tiny_photometric.json"),
                "-o", os.path.join(out, "masked.spar")]) != 0:
        raise SystemExit("make_mask_model: spar-convert failed")
    return 0


if __name__ == "__main__":
    sys.exit(make(*(os.path.abspath(a) for a in sys.argv[1:3])))
