#!/usr/bin/python3
"""Test fixture for the model-level tests (tests/test_spar_*.cpp): a tiny SPAR without the
semantic branch (the tiny preset with use_lseg false), perturbed so every bias and statistic
matters, packed by the converter, and the PyTorch reference's goldens of every stage for a few
view orders. Everything is made here, at test time, from fixed seeds.

    make_spar_goldens.py OUT_DIR
    make_spar_goldens.py --full OUT_DIR [BPE.txt.gz]   (the full-size case, see main_full)
    make_spar_goldens.py --semantic OUT_DIR BPE.txt.gz   (the semantic branch, see main_semantic)

writes OUT_DIR/
    tiny_photometric.json     the configuration (SparConfig.to_dict())
    frame_0.png .. frame_4.png  procedural frames (160x120: resized and cropped to 128x128)
    tiny.pt, tiny.spar        checkpoint and packed model
    interleaved/              goldens: frames 0..4, inputs 0,2,4, targets 1,3
    odd_targets/              goldens: frames 0..4, inputs 1,3, targets 0,2,4 (canonical = target)
    path/                     goldens: inputs frame_0, frame_2, frame_4, a 3-camera path
    static/                   goldens: as interleaved with --assume-static (no DINOv3, CV-DRP, gating)
  stiff cases (the model-level ones of engineering.md), each a goldens directory:
    identical_views/          all five frames the same image
    black_view/               frame 2 (an input, the canonical view) all black
    all_dynamic/, all_static/ a model whose CV-DRP head bias is +40 / -40: P(dynamic) = 1 / ~0
                              everywhere (gating with s = 0 everywhere / s = 1)
    focal_large/, focal_small/ a model whose canonical_k_head predicts focal 1001.25 / 0.001
  and what single test programs read beyond those (made here once per build, not once per test):
    tiny16.spar               tiny.pt packed with --fp16
    tiny_q8.spar, tiny_q4.spar tiny.pt packed with --weights q8 / q4
    dino/                     make_dino_golden.py: DINOv3 on constant and non-square images
    cv_drp/                   make_cv_drp_golden.py: pairs.json and identical/
    masked/                   make_mask_model.py: masked.pt / masked.spar (mixed motion masks)
    tiny_sam2.spar            masked.pt packed with a tiny SAM2.1 (make_sam2_path_golden.py's QUICK_CONFIG;
                              tiny_sam2_weights.pt, tiny_sam2_config.json: its checkpoint and variant)
--semantic writes the tiny semantic model, its goldens (semantic/, semantic_path/), and
    label_render/             spar-reference render --labels of the semantic case
    lseg/                     make_lseg_golden.py: LSeg on constant and non-square images
    text/, text_random/       make_text_golden.py: tests/data/text_prompts.json with embeddings,
                              4000 random prompts (seed 11)
Every tool runs in this process (one torch import for the whole fixture).
"""
import json
import os
import shutil
import sys

import numpy as np
from PIL import Image

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))

from spar_convert.model_config import full, tiny  # noqa: E402


def tiny_sam2(ck, cfg_path, out):
    """tiny_sam2.spar: checkpoint ck (make_mask_model.py's) with make_sam2_path_golden.py's quick SAM2.1
    variant (random weights; the checkpoint and its config beside it, for the reference)."""
    import torch
    from make_sam2_path_golden import QUICK_CONFIG
    from spar_reference import sam2
    sam2_ck, sam2_cfg = os.path.join(out, "tiny_sam2_weights.pt"), os.path.join(out, "tiny_sam2_config.json")
    torch.save(sam2.make_checkpoint(QUICK_CONFIG, seed=21), sam2_ck)
    with open(sam2_cfg, "w") as f:
        json.dump(QUICK_CONFIG.to_dict(), f)
    convert("-q", ck, "--config", cfg_path, "--sam2", sam2_ck, "--sam2-config", sam2_cfg,
            "-o", os.path.join(out, "tiny_sam2.spar"))


def frames(out_dir, count=5, width=160, height=120, seed=3):
    """A textured static background and a disk that moves from frame to frame."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    base = np.stack([0.5 + 0.4 * np.sin(xx / 9.0 + c) * np.cos(yy / 13.0 - c) for c in range(3)], -1)
    base += 0.08 * rng.standard_normal(base.shape)
    paths = []
    for i in range(count):
        img = base.copy()
        # the camera pans a little: shift the background
        img = np.roll(img, shift=2 * i, axis=1)
        cx, cy = 30 + 22 * i, 40 + 8 * i
        disk = (xx - cx) ** 2 + (yy - cy) ** 2 < 15 ** 2
        img[disk] = [0.9, 0.2, 0.1]
        p = os.path.join(out_dir, f"frame_{i}.png")
        Image.fromarray((np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)).save(p)
        paths.append(p)
    return paths


def variant(ck, out, changes):
    """A copy of checkpoint ``ck`` with some tensors replaced: name -> function(tensor)."""
    import torch
    sd = torch.load(ck, map_location="cpu")
    model = sd["model"]
    for name, fn in changes.items():
        model[name] = fn(model[name].clone())
    torch.save(sd, out)


def reference(*argv, state_dict=None):
    """spar-reference ARGV in this process (one torch import for the whole fixture);
    state_dict: the checkpoint's tensors when this process holds them (spar_reference.cli.main)."""
    from spar_reference.cli import main as reference_main
    if argv[0] in ("goldens", "render"):
        # One torch thread: the fixture runs beside another test (ctest -j2), where two threads
        # made the tiny model's forwards slower and their time erratic (measured 4.5 against
        # 5.7-10 s for --semantic with the other core busy). The full-size case keeps two.
        argv = argv + ("--threads", str(THREADS))
    if reference_main([str(a) for a in argv], state_dict=state_dict) != 0:
        raise SystemExit("make_spar_goldens: spar-reference %s failed" % argv[0])


def convert(*argv):
    """spar-convert ARGV in this process."""
    from spar_convert.convert import main as convert_main
    if convert_main([str(a) for a in argv]) != 0:
        raise SystemExit("make_spar_goldens: spar-convert failed: %s" % " ".join(map(str, argv)))


THREADS = 1


def fresh(d):
    """d, emptied: a fixture made again replaces what it made before."""
    shutil.rmtree(d, ignore_errors=True)
    return d


# CLIP's merges table: the repository's copy unless the command line names another.
REPO_BPE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "text", "data", "clip",
                        "bpe_simple_vocab_16e6.txt.gz")


def require_bpe(bpe):
    if not os.path.isfile(bpe):
        raise SystemExit("make_spar_goldens: CLIP BPE merges table not found: %s" % bpe)
    return bpe


def main_full(out, bpe):
    """The full-size comparison (issues: one run of the official configuration with random
    weights, 2 input + 1 target view, stage by stage; the semantic branch at full size): full()
    as spar.yaml has it (LSeg ViT-L/16, CLIP text), perturbed weights, float64 goldens of frames
    0, 1, 2 with inputs 0, 2, with --labels. At 64x64 rather than the official 256x256: every
    weight, width and depth is the official model's (the tensors over a storage binding's 128 MiB
    included), and the image tokens are few (16 a view): the suite's longest chain measures the
    depths and widths, other sizes are test_spar_size's (measured alone: the engine's run 29 s at
    128x128, 13 s at 64x64, largest stage NMSE 3.6e-12 and 2.9e-12). The backbones are built
    without torch.nn.init's values, which their seeded randomization overwrites (6.6 s)."""
    os.makedirs(out, exist_ok=True)
    cfg = full()
    cfg.image_height = cfg.image_width = 64
    cfg_path = os.path.join(out, "full.json")
    with open(cfg_path, "w") as f:
        json.dump(cfg.validate().to_dict(), f, indent=1)
    f = frames(out, count=3, width=320, height=240)
    ck, packed = os.path.join(out, "full.pt"), os.path.join(out, "full.spar")
    require_bpe(bpe)
    # spar-reference make-checkpoint --seed 11 --perturb --no-optimizer, in this process: the
    # 3 GB of tensors are kept for the goldens below instead of being read back from the file
    # (which only the converter needs)
    from spar_reference.cli import save_checkpoint, test_checkpoint
    tensors = test_checkpoint(cfg, 11, perturb=True, optimizer_state=False, backbone_init=False)
    save_checkpoint(tensors, ck)
    convert("-q", ck, "--config", cfg_path, "--bpe", bpe, "-o", packed)
    os.unlink(ck)  # 3 GB: only the packed file is needed from here on
    d = fresh(os.path.join(out, "full_2in_1out"))
    labels = ["--labels", ",".join(LABELS[:4]), "--bpe", bpe]
    reference("goldens", "--checkpoint", ck, "--config", cfg_path, "--frames", *f, "--inputs", "0,2",
              *labels, "--float64", "--out", d, state_dict=tensors["model"])
    return 0


TEXT_PROMPTS = os.path.join(ROOT, "tests", "data", "text_prompts.json")
LABELS = ["sofa", "window", "person", "floor", "ünïcödé chäir",
          "a " + "very " * 90 + "long prompt that CLIP truncates at 77 tokens"]


def main_semantic(out, bpe):
    """The semantic branch (issue: LSeg features, semantic tokens and head, CLIP text, label
    maps): the tiny preset as it is (use_lseg true, semantic queries in the decoder), perturbed,
    packed with the CLIP BPE table, float64 goldens with --labels."""
    os.makedirs(out, exist_ok=True)
    cfg = tiny()
    cfg_path = os.path.join(out, "tiny_semantic.json")
    with open(cfg_path, "w") as f:
        json.dump(cfg.validate().to_dict(), f, indent=1)
    f = frames(out)
    ck, packed = os.path.join(out, "tiny_semantic.pt"), os.path.join(out, "tiny_semantic.spar")
    reference("make-checkpoint", "--config", cfg_path, "--seed", "7", "--perturb", "--no-optimizer", "-o", ck)
    require_bpe(bpe)
    convert("-q", ck, "--config", cfg_path, "--bpe", bpe, "-o", packed)
    # and with --weights q8: LSeg's and CLIP's matrices under the rule (tests/test_spar_precision.cpp)
    convert("-q", "--weights", "q8", ck, "--config", cfg_path, "--bpe", bpe, "-o",
            os.path.join(out, "tiny_semantic_q8.spar"))
    with open(os.path.join(out, "labels.json"), "w") as fh:
        json.dump(LABELS, fh, ensure_ascii=False)
    labels = ["--labels", ",".join(LABELS), "--bpe", bpe]
    for name, args in {"semantic": ["--frames", *f, "--inputs", "0,2,4"],
                       "semantic_path": ["--images", f[0], f[2], f[4], "--path", "3"]}.items():
        reference("goldens", "--checkpoint", ck, "--config", cfg_path, *args, *labels, "--float64",
                  "--out", fresh(os.path.join(out, name)))
    # What tests/test_label_maps.cpp compares its label map files with: the reference's render.
    reference("render", "--checkpoint", ck, "--config", cfg_path, "--frames", *f, "--inputs", "0,2,4",
              *labels, "--out", fresh(os.path.join(out, "label_render")))
    # LSeg cases beyond the model's (tests/test_lseg.cpp): constant, non-square, input_norm lseg.
    import make_lseg_golden
    make_lseg_golden.main(["--checkpoint", ck, "--config", cfg_path, "--out", fresh(os.path.join(out, "lseg"))])
    # The text side (tests/test_bpe_tokenizer.cpp, tests/test_clip_text.cpp): the prompts of
    # tests/data/text_prompts.json with the CLIP text encoder's embeddings, and 4000 random prompts.
    import make_text_golden
    make_text_golden.main(["--bpe", bpe, "--prompts", TEXT_PROMPTS, "--checkpoint", ck, "--config", cfg_path,
                           "--out", fresh(os.path.join(out, "text"))])
    make_text_golden.main(["--bpe", bpe, "--random", "4000", "--seed", "11",
                           "--out", fresh(os.path.join(out, "text_random"))])
    return 0


def main():
    global THREADS
    if sys.argv[1:2] == ["--full"]:
        THREADS = 2
        return main_full(os.path.abspath(sys.argv[2]), sys.argv[3] if len(sys.argv) > 3 else REPO_BPE)
    if sys.argv[1:2] == ["--semantic"]:
        return main_semantic(os.path.abspath(sys.argv[2]), sys.argv[3] if len(sys.argv) > 3 else REPO_BPE)
    out = os.path.abspath(sys.argv[1])
    os.makedirs(out, exist_ok=True)
    cfg = tiny()
    cfg.use_lseg = False
    cfg_path = os.path.join(out, "tiny_photometric.json")
    with open(cfg_path, "w") as f:
        json.dump(cfg.validate().to_dict(), f, indent=1)
    f = frames(out)
    ck, packed = os.path.join(out, "tiny.pt"), os.path.join(out, "tiny.spar")
    reference("make-checkpoint", "--config", cfg_path, "--seed", "7", "--perturb", "--no-optimizer", "-o", ck)
    convert("-q", ck, "--config", cfg_path, "-o", packed)
    # The same checkpoint packed with --fp16 (tests/test_spar_precision.cpp).
    convert("-q", "--fp16", ck, "--config", cfg_path, "-o", os.path.join(out, "tiny16.spar"))
    for q in ("q8", "q4"):  # and quantized (tests/test_spar_precision.cpp)
        convert("-q", "--weights", q, ck, "--config", cfg_path, "-o", os.path.join(out, "tiny_%s.spar" % q))
    cases = {
        "interleaved": ["--frames", *f, "--inputs", "0,2,4"],
        "odd_targets": ["--frames", *f, "--inputs", "1,3"],
        "path": ["--images", f[0], f[2], f[4], "--path", "3"],
        "static": ["--frames", *f, "--inputs", "0,2,4", "--assume-static"],
    }
    # stiff inputs
    same = [f[0]] * 5
    black = os.path.join(out, "black.png")
    Image.new("RGB", (160, 120)).save(black)
    cases["identical_views"] = ["--frames", *same, "--inputs", "0,2,4"]
    cases["black_view"] = ["--frames", f[0], f[1], black, f[3], f[4], "--inputs", "0,2,4"]
    # stiff models
    head = "cv_drp.estimator.dpt_decoder.head.bias"
    kw, kb = "pose_predictor.canonical_k_head.2.weight", "pose_predictor.canonical_k_head.2.bias"
    models = {
        "all_dynamic": {head: lambda t: t.fill_(40.0)},
        "all_static": {head: lambda t: t.fill_(-40.0)},
        "focal_large": {kw: lambda t: t.zero_(), kb: lambda t: t.fill_(1000.0)},
        "focal_small": {kw: lambda t: t.zero_(), kb: lambda t: t.fill_(-1.249)},
    }
    model_ck = {}
    for name, changes in models.items():
        mck = os.path.join(out, f"{name}.pt")
        variant(ck, mck, changes)
        convert("-q", mck, "--config", cfg_path, "-o", os.path.join(out, f"{name}.spar"))
        model_ck[name] = mck
        cases[name] = ["--frames", *f, "--inputs", "0,2,4"]
    for name, args in cases.items():
        reference("goldens", "--checkpoint", model_ck.get(name, ck), "--config", cfg_path, *args, "--float64",
                  "--out", fresh(os.path.join(out, name)))
    # Stage-level cases beyond the model's: DINOv3 on constant and non-square images
    # (tests/test_dino_v3.cpp), CV-DRP's view pairs and all views identical (tests/test_cv_drp.cpp).
    import make_cv_drp_golden
    import make_dino_golden
    make_dino_golden.main(["--checkpoint", ck, "--config", cfg_path, "--out", fresh(os.path.join(out, "dino"))])
    os.makedirs(fresh(os.path.join(out, "cv_drp")))
    make_cv_drp_golden.pairs(os.path.join(out, "cv_drp", "pairs.json"))
    make_cv_drp_golden.identical(out, os.path.join(out, "cv_drp", "identical"))
    # A variant whose motion masks hold both values (tests/test_spar_render.cpp).
    import make_mask_model
    make_mask_model.make(out, fresh(os.path.join(out, "masked")))
    # That variant with a tiny SAM2.1 (the variant of tests/test_sam2_path.cpp's goldens, random
    # weights): the refinement wired into a request, spar render and spar eval. Its mixed masks
    # make SAM2 refine views (an empty mask is skipped: no encoder would run).
    tiny_sam2(os.path.join(out, "masked", "masked.pt"), cfg_path, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
