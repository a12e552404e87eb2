#!/usr/bin/python3
"""Fixture of the image-size tests (tests/test_spar_size.cpp, converter/tests/test_convert.py):
a tiny SPAR "trained" at 128x128 (the tiny preset without the semantic branch, perturbed
weights), whose DINOv3 is the tiny one (width 64, 2 heads, 2 blocks: not ViT-B), the
official-format YAML that describes it as configs/spar/spar.yaml would (its size under
model.target_image and model.image_tokenizer, model.dino_v3 naming the released vitb16 with
only the width changed: the YAML does not hold DINOv3's heads or depth), and the checkpoint
packed by spar-convert with that YAML.

    make_size_model.py OUT_DIR

writes OUT_DIR/spar.yaml, size128.pt, size128.spar and frame_0.png .. frame_2.png (160x120).
"""
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))

from spar_convert.model_config import tiny  # noqa: E402

SIZE = 128  # the training size the YAML states (the tiny preset's)


def photometric_config():
    """The tiny preset without the semantic branch, at SIZE x SIZE."""
    cfg = tiny()
    cfg.use_lseg = False
    cfg.image_height = cfg.image_width = SIZE
    return cfg.validate()


def official_yaml(cfg):
    """The structure of the official configs/spar/spar.yaml with cfg's sizes (no lseg section:
    the semantic branch is off, as use_lseg is false without model.lseg.checkpoint_path)."""
    return {
        "model": {
            "class_name": "model.spar.SPAR",
            "image_tokenizer": {"image_size": cfg.image_height, "patch_size": cfg.patch_size,
                                "in_channels": 3},
            "input_with_pe": True,
            "target_image": {"height": cfg.image_height, "width": cfg.image_width,
                             "patch_size": cfg.patch_size, "in_channels": 6},
            "transformer": {"d": cfg.d, "d_head": cfg.d_head,
                            "encoder_n_layer": cfg.encoder_n_layer,
                            "encoder_geom_n_layer": cfg.encoder_geom_n_layer,
                            "decoder_n_layer": cfg.decoder_n_layer, "special_init": True,
                            "depth_init": True, "use_qk_norm": True},
            "scene_latent": {"length": cfg.scene_tokens},
            "pose_latent": {"length": 1, "canonical": cfg.canonical, "representation": "6d"},
            "dino_v3": {"checkpoint_path":
                        "./datasets/pretrained/dinov3_vitb16_pretrain_lvd1689m-73cec8be.pth",
                        "arch": "vitb16", "embed_dim": cfg.dino_width},
            "cv_drp": {"mask_threshold": cfg.mask_threshold, "vit_n_heads": cfg.cv_drp_n_heads,
                       "vit_n_layers": cfg.cv_drp_n_layer},
        },
        "training": {"num_views": cfg.num_views, "num_input_views": cfg.num_input_views,
                     "semantic_loss_weight": 0.1},
    }


def write_yaml(path, cfg):
    import yaml
    with open(path, "w") as fh:
        yaml.safe_dump(official_yaml(cfg), fh, sort_keys=False)


def main(out):
    import torch
    from make_spar_goldens import frames
    from spar_reference import make_checkpoint
    os.makedirs(out, exist_ok=True)
    cfg = photometric_config()
    yaml_path, ck = os.path.join(out, "spar.yaml"), os.path.join(out, "size128.pt")
    write_yaml(yaml_path, cfg)
    torch.save(make_checkpoint(cfg, seed=9, perturb=True, optimizer_state=False), ck)
    from spar_convert.convert import main as convert
    if convert(["-q", ck, "--config", yaml_path, "-o", os.path.join(out, "size128.spar")]) != 0:
        raise SystemExit("make_size_model: spar-convert failed")
    frames(out, count=3)
    return 0


if __name__ == "__main__":
    sys.exit(main(os.path.abspath(sys.argv[1])))
