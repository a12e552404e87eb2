#!/usr/bin/python3
"""How far the official CUDA path's fp16 label scores are from the engine's fp32 ones.

The official code (LSeg lseg_net.py, as SPAR runs it on a GPU) computes the label scores as
`logit_scale * image_features.half() @ text_features.t()` with CLIP's text features in fp16 too,
then `.float()` and `scratch.output_conv` (x2 bilinear, align_corners=True) before the argmax.
The engine computes the same formula in fp32 (model/label_maps.h). This emulates the fp16
product on the CPU (operands rounded to fp16, fp32 accumulation as cuBLAS does, the product
rounded to fp16) from a goldens directory of `spar-reference goldens --labels --float64`
(semantic_features.npy, text_embeddings.npy) and prints, against float64: the largest score
error of each, and the share of full-resolution label pixels each gives another label, and
between the two.

    /usr/bin/python3 scripts/compare/label_precision.py GOLDENS_DIR [...]
      e.g. build/tests/spar_goldens_semantic/semantic build/tests/spar_goldens_full/full_2in_1out
"""
import os
import sys

import numpy as np
import torch
import torch.nn.functional as F

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# The repository's Python roots this program imports from, found from here (nothing installed).
sys.path[:0] = [os.path.join(ROOT, d) for d in ("reference", "converter")]

from spar_reference.clip_text import LSEG_LOGIT_SCALE  # noqa: E402


def normalized(goldens):
    feat = torch.from_numpy(np.load(os.path.join(goldens, "semantic_features.npy"))).double()
    if feat.dim() == 5:  # [1, R, C, h, w]: the reference keeps the batch
        feat = feat[0]
    txt = torch.from_numpy(np.load(os.path.join(goldens, "text_embeddings.npy"))).double()
    return feat / feat.norm(dim=1, keepdim=True), txt / txt.norm(dim=-1, keepdim=True)


def scores(img, txt, mode):
    """[R, P, h, w] label scores: float64, the engine's fp32 formula, or the CUDA fp16 one."""
    if mode == "float64":
        return LSEG_LOGIT_SCALE * torch.einsum("rchw,pc->rphw", img, txt)
    if mode == "fp32":
        return (LSEG_LOGIT_SCALE * torch.einsum("rchw,pc->rphw", img.float(), txt.float())).double()
    scaled = (LSEG_LOGIT_SCALE * img.half().float()).half()          # logit_scale * features.half()
    prod = torch.einsum("rchw,pc->rphw", scaled.float(), txt.half().float())  # fp32 accumulation
    return prod.half().double()                                       # the product in fp16, .float()


def labels(s):
    return F.interpolate(s, scale_factor=2, mode="bilinear", align_corners=True).argmax(dim=1)


def main(argv):
    if not argv:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    for goldens in argv:
        img, txt = normalized(goldens)
        exact = scores(img, txt, "float64")
        ref = labels(exact)
        row = {m: scores(img, txt, m) for m in ("fp32", "fp16")}
        lab = {m: labels(s) for m, s in row.items()}
        n = ref.numel()
        print("%s: %d views, %d prompts, %dx%d label maps" % (goldens, ref.shape[0], txt.shape[0],
                                                             ref.shape[1], ref.shape[2]))
        for m in ("fp32", "fp16"):
            print("  %-4s scores max abs error %.2e; labels differing from float64's %.3f %%"
                  % (m, (row[m] - exact).abs().max().item(), 100.0 * (lab[m] != ref).sum().item() / n))
        print("  fp16 against fp32: labels differing %.3f %%"
              % (100.0 * (lab["fp16"] != lab["fp32"]).sum().item() / n))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
