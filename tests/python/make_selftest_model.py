#!/usr/bin/python3
"""Makes the self-test model of `spar selftest` (data/selftest).

Makes the self-test model that `spar selftest` runs stage by stage (data/selftest/,
installed as share/spar/selftest/): a tiny SPAR with every stage of the full model (view
tokens, pose estimator and heads, Plücker rays, DINOv3, CV-DRP, gating, LSeg, semantic tokens,
scene encoder, renderer with its semantic head, CLIP's text tower with the full vocabulary at
width 16, label maps) at 64x64 pixels and D 32, perturbed so every bias and statistic matters,
packed with a tiny SAM2.1 (sam2_config(): padded windows, q pooling, a global block; the
refinement of every view's motion mask, at 256x256 images: SAM2.1's path at a sixteenth of
the official 1024x1024's work), with every weight rounded to a value fp16 holds exactly.
Packed with --fp16 (2.6 MB instead of 5.2), the file then holds the very model the float64 reference ran: a device with fp16 storage reads the weights as
fp16, one without widens them to fp32, and both are compared with the same float64 outputs.

    /usr/bin/python3 tests/python/make_selftest_model.py [OUT_DIR]     (default data/selftest)

writes OUT_DIR/
    model.spar        the packed model (with CLIP's merges table, as any semantic pack)
    images.npy        the five prepared input frames [5, 3, 64, 64] (float32: what the engine reads)
    reference/*.npy   the PyTorch reference's float64 output of the stages `spar selftest` checks
                      (refined_input / refined_target: SAM2's masks of CV-DRP's P(dynamic), 0/1,
                      with *.logits.npy, the chosen logits at full size, for ties at 0;
                      refine_iou [views, 3] and refine_logits [views, 64, 64] (float32), inputs
                      then targets),
                      the prompts' token ids (text_tokens: the tokenizer has tests of its own) and
                      label_maps.gap (each full-resolution pixel's top-two score gap: near-ties)
    manifest.json     inputs, targets, prompts, the stages in pipeline order, how this was made
Deterministic: the same torch makes the same files (tests/CMakeLists.txt: selftest_model_remade),
on any x86-64 machine with AVX2: OpenBLAS rounds float64 products differently with the kernels
it picks for each CPU family and cache size, so this program fixes them (Haswell's, a 512 KB L2)
before numpy or torch loads it. Needs Debian's python3-torch; the engine and its tests need only
what this writes.
"""
import json
import os
import shutil
import sys
import tempfile

os.environ.update(OPENBLAS_CORETYPE="Haswell", OPENBLAS_L2_SIZE="512")
import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
# The repository's Python roots this program imports from, found from here (nothing installed).
sys.path[:0] = [os.path.join(ROOT, d) for d in ("reference", "converter")]

from spar_convert.convert import BN_EPS  # noqa: E402
from spar_convert.model_config import tiny  # noqa: E402
from spar_convert.sam2_config import Sam2Config  # noqa: E402

SIZE = 64
INPUTS, TARGETS = [0, 2, 4], [1, 3]
PROMPTS = ["wall", "floor", "sofa", "person"]
# The stages checked, in pipeline order (goldens.py names; what SparPipeline keeps under the
# same names; the last three are the label stages'). Enough to place a failure in one stage
# without shipping every intermediate.
STAGES = ["img_tokens", "cam_tokens", "c2w", "fxfycxcy", "ray_tokens", "dino",
          "cv_drp_input.prob", "cv_drp_input.binary", "cv_drp_target.prob", "cv_drp_target.binary",
          "gated_tokens", "lseg_features", "semantic_tokens", "scene_tokens", "decoder_out", "rgb",
          "semantic_out_tokens", "semantic_features", "text_embeddings", "label_logits", "label_maps",
          "refined_input", "refined_target", "refine_iou", "refine_logits"]
# The SAM2.1 variant: make_sam2_path_golden.py's QUICK_CONFIG (q pooling, windows of 6 padded
# on 64x64 and of 3 on 32x32, a global block over the 32x32 map's 1024 tokens), named here.
def sam2_config():
    from make_sam2_path_golden import QUICK_CONFIG
    return Sam2Config(**dict(QUICK_CONFIG.to_dict(), name="selftest")).validate()


# CV-DRP's P(dynamic) is the prompt's threshold at 0.5: a device must put every pixel on the
# reference's side of it, so no pixel may lie closer to 0.5 than this (the engine's P is within
# 1e-7 of the float64 reference's on lavapipe).
PROMPT_MARGIN = 1e-5


def selftest_config():
    """tiny() made smaller where its size is only bytes: D 32 (DINOv3's too), CLIP's text tower at width 16
    (the full 49408-token vocabulary), semantic features of 16 channels from a hidden layer of 4."""
    cfg = tiny()
    cfg.image_height = cfg.image_width = SIZE
    cfg.d, cfg.d_head = 32, 16
    cfg.semantic_dim, cfg.semantic_hidden = 16, 4
    cfg.clip = dict(cfg.clip, width=16, heads=2, embed_dim=16)
    cfg.lseg = dict(cfg.lseg, feature_dim=16)
    cfg.dino = dict(cfg.dino, embed_dim=32)  # DINOv3's width is D (CV-DRP concatenates them)
    return cfg.validate()


def refine(sd, cfg, images, goldens, out):
    """The reference's SAM2.1 refinement of CV-DRP's float64 masks (inputs, then targets, as the
    engine refines them with targetMotion) into OUT/refined_*.npy, refine_iou.npy, refine_logits.npy."""
    import torch
    import torch.nn.functional as F
    from spar_reference import sam2
    ious, low_res = [], []
    for which, views in (("input", INPUTS), ("target", TARGETS)):
        prob = np.load(os.path.join(goldens, "cv_drp_%s.prob.npy" % which))[0, :, 0]  # [V, H, W]
        margin = float(np.abs(prob - 0.5).min())
        assert margin > PROMPT_MARGIN, "cv_drp_%s: a pixel %.1e from 0.5, the prompt's threshold" % (which, margin)
        results = sam2.refine_masks(sd, cfg, torch.from_numpy(images[views]), torch.from_numpy(prob))
        refined, logits = [], []
        for r in results:
            assert not r["skipped"], "a view SAM2 skips: the check would run no encoder"
            refined.append(r["refined"].numpy())
            full = F.interpolate(r["logits"][None, None], size=prob.shape[1:], mode="bilinear", align_corners=False)
            logits.append(full[0, 0].numpy())
            ious.append(r["iou"].numpy())
            low_res.append(r["logits"].numpy())
        share = float(np.mean(refined))
        assert 0.05 < share < 0.95, "refined_%s: %.3f of the pixels dynamic, not a mixed mask" % (which, share)
        np.save(os.path.join(out, "refined_%s.npy" % which), np.stack(refined))
        np.save(os.path.join(out, "refined_%s.logits.npy" % which), np.stack(logits))
    np.save(os.path.join(out, "refine_iou.npy"), np.stack(ious))
    # float32: 1.3 MB instead of 2.6 in the repository; its rounding (NMSE ~1e-15) is far below
    # the bound the engine's logits are held to
    np.save(os.path.join(out, "refine_logits.npy"), np.stack(low_res).astype(np.float32))


def main(argv):
    out = os.path.abspath(argv[0] if argv else os.path.join(ROOT, "data", "selftest"))
    import torch
    from make_spar_goldens import frames
    from spar_convert.convert import main as convert
    from spar_reference import sam2
    from spar_reference.cli import main as reference

    work = tempfile.mkdtemp(prefix="selftest-model-")
    try:
        cfg = selftest_config()
        cfg_path = os.path.join(work, "selftest.json")
        with open(cfg_path, "w") as f:
            json.dump(cfg.validate().to_dict(), f, indent=1)
        ck = os.path.join(work, "selftest.pt")
        if reference(["make-checkpoint", "--config", cfg_path, "--seed", "17", "--perturb", "--no-optimizer",
                      "-o", ck, "--threads", "1"]) != 0:
            raise SystemExit("make_selftest_model: make-checkpoint failed")
        sd = torch.load(ck, map_location="cpu")
        for name, t in sd["model"].items():
            if t.is_floating_point():
                sd["model"][name] = t.half().float()
        # LSeg's BatchNorms are folded into their convolutions by the converter, whose --fp16
        # pack would round the folded kernels (w * gamma / sqrt(var + eps)) off the model the
        # reference runs. gamma = sqrt(var + eps) makes that factor 1 to float32's precision, so
        # the folded kernels are the fp16-exact ones; the statistics and beta stay perturbed.
        for name in [n for n in sd["model"] if n.endswith(".running_var")]:
            gamma = name[:-len("running_var")] + "weight"
            sd["model"][gamma] = torch.sqrt(sd["model"][name].double() + BN_EPS).float()
        torch.save(sd, ck)
        files = frames(work, count=5, width=SIZE, height=SIZE, seed=5)
        goldens_args = ["goldens", "--checkpoint", ck, "--config", cfg_path, "--frames", *files,
                        "--inputs", ",".join(map(str, INPUTS)), "--labels", ",".join(PROMPTS), "--float64",
                        "--threads", "1"]
        # Mixed motion masks: the random CV-DRP's logits are nearly constant (P(dynamic) ~0.25
        # everywhere, every mask empty, a mask check that compares nothing). Scale its head by
        # a power of two (fp16-exact stays exact) and centre the logits at 0 (as
        # tests/python/make_mask_model.py does for the tests' model). The gain multiplies the
        # engine's error in P(dynamic) too while P stays near 0.5, so its NMSE grows as gain^2
        # (at 128, before the BatchNorms below were made fp16-exact, P measured NMSE 2.9e-10,
        # above the model tests' 1e-10 bound, model/stage_tolerances.h); 16 spreads P enough.
        first = os.path.join(work, "first")
        if reference(goldens_args + ["--out", first]) != 0:
            raise SystemExit("make_selftest_model: spar-reference goldens failed")
        logits = np.load(os.path.join(first, "cv_drp_input.logits.npy"))
        head, gain = "cv_drp.estimator.dpt_decoder.head", 16.0
        bias = float(sd["model"][head + ".bias"][0])
        sd["model"][head + ".weight"] *= gain
        sd["model"][head + ".bias"] = torch.full_like(sd["model"][head + ".bias"],
                                                      -gain * (float(logits.mean()) - bias)).half().float()
        # Mixed label maps likewise: the random semantic features share one direction, so one
        # prompt wins everywhere. Centre them (the expansion's bias less their mean over the
        # pixels): their directions then spread over the prompts.
        feats = np.load(os.path.join(first, "semantic_features.npy"))  # [1, R, C, h, w]
        expansion = "semantic_feature_expansion.1.bias"
        sd["model"][expansion] = (sd["model"][expansion] -
                                  torch.from_numpy(feats.mean(axis=(0, 1, 3, 4))).float()).half().float()
        torch.save(sd, ck)
        sam2_cfg = sam2_config()
        sam2_sd = sam2.make_checkpoint(sam2_cfg, seed=23)
        sam2_sd["model"] = {k: t.half().float() if t.is_floating_point() else t for k, t in sam2_sd["model"].items()}
        torch.save(sam2_sd, os.path.join(work, "selftest_sam2.pt"))
        with open(os.path.join(work, "selftest_sam2.json"), "w") as f:
            json.dump(sam2_cfg.to_dict(), f)
        stage = out + ".tmp"
        shutil.rmtree(stage, ignore_errors=True)
        os.makedirs(os.path.join(stage, "reference"))
        # From the work directory with relative names: the pack records its sources' paths, and a
        # temporary directory's name would make every run's file differ.
        here = os.getcwd()
        os.chdir(work)
        try:
            if convert(["-q", "--fp16", "selftest.pt", "--config", "selftest.json", "--sam2", "selftest_sam2.pt",
                        "--sam2-config", "selftest_sam2.json", "-o", os.path.join(stage, "model.spar")]) != 0:
                raise SystemExit("make_selftest_model: spar-convert failed")
        finally:
            os.chdir(here)
        goldens = os.path.join(work, "goldens")
        if reference(goldens_args + ["--out", goldens]) != 0:
            raise SystemExit("make_selftest_model: spar-reference goldens failed")
        images = np.load(os.path.join(goldens, "images.npy"))
        # 8-bit pixels / 255: the engine's image preparation rounds that to float32, as here.
        assert np.array_equal(np.round(images * 255), images * 255), "prepared images are not 8-bit values"
        np.save(os.path.join(stage, "images.npy"), images.astype(np.float32))
        for mask in ("cv_drp_input", "cv_drp_target"):
            share = float(np.load(os.path.join(goldens, mask + ".binary.npy")).mean())
            assert 0.1 < share < 0.9, "%s: %.3f of the pixels dynamic, not a mixed mask" % (mask, share)
        refine(sam2_sd["model"], sam2_cfg, images.reshape(-1, 3, SIZE, SIZE).astype(np.float32), goldens, os.path.join(stage, "reference"))
        for name in [n for n in STAGES if not n.startswith("refine")] + ["text_tokens"]:
            shutil.copy(os.path.join(goldens, name + ".npy"), os.path.join(stage, "reference", name + ".npy"))
        # Where two labels nearly tie at full resolution (the logits x2, float64): a device may
        # round such a pixel either way, and the self-test allows it only there.
        up = torch.nn.functional.interpolate(torch.from_numpy(np.load(os.path.join(goldens, "label_logits.npy"))),
                                             scale_factor=2, mode="bilinear", align_corners=True)
        top2 = up.topk(2, dim=1).values
        np.save(os.path.join(stage, "reference", "label_maps.gap.npy"), (top2[:, 0] - top2[:, 1]).numpy())
        maps = np.load(os.path.join(goldens, "label_maps.npy"))
        shares = sorted((np.bincount(maps.reshape(-1), minlength=len(PROMPTS)) / maps.size).tolist())
        assert shares[-2] > 0.05, "label maps of one label (shares %s): a check that compares little" % shares
        manifest = {
            "what": "spar selftest's model: tiny SPAR with the semantic branch at 64x64 and a tiny SAM2.1, weights fp16-exact, "
                    "PyTorch reference outputs in float64 (tests/python/make_selftest_model.py)",
            "inputs": INPUTS, "targets": TARGETS, "views": len(files), "prompts": PROMPTS, "stages": STAGES,
            "torch": torch.__version__, "seed": 17,
        }
        with open(os.path.join(stage, "manifest.json"), "w") as f:
            json.dump(manifest, f, indent=1)
            f.write("\n")
        shutil.rmtree(out, ignore_errors=True)
        os.rename(stage, out)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    total = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(out) for f in fs)
    print("make_selftest_model: %s (%.2f MB)" % (out, total / 1e6))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
