"""The small SPAR trained here: every size of the official architecture scaled down so one
training run fits about half an hour on two CPU cores. 128x128 images with patch 16 (the
CV-DRP decoder upsamples by exactly 16), 8 views a scene as the official training samples."""
import copy

from spar_convert.model_config import SparConfig, backbone_config


def small_config(image_size: int = 128, scene_tokens: int = 64) -> SparConfig:
    """image_size: square input/render size, a multiple of the patch size 16 (the CV-DRP
    decoder upsamples by exactly 16); 128 for the shipped model. scene_tokens: the latent the
    scene encoder fills, 64 for the shipped model (one view's patches at 128x128)."""
    if image_size < 32 or image_size % 16:
        raise ValueError(f"image size {image_size} must be a multiple of 16, at least 32")
    dino = dict(backbone_config("dino", "tiny"), arch="small-random", embed_dim=128, depth=2,
                num_heads=4)
    lseg = dict(backbone_config("lseg", "tiny"), backbone="small", width=96, depth=4,
                num_heads=4, pretrain_img_size=image_size, hooks=[0, 1, 2, 3],
                reassemble=[24, 48, 96, 96], features=32, feature_dim=32)
    # CLIP's real vocabulary (49408 tokens) and context; a narrow width keeps the token
    # embedding table, the biggest tensor of the model, at 6 MB.
    clip = dict(backbone_config("clip", "tiny"), width=32, layers=2, heads=2, embed_dim=32)
    return SparConfig(
        d=128, d_head=32,
        encoder_n_layer=3, encoder_geom_n_layer=3, decoder_n_layer=3,
        cv_drp_n_layer=2, cv_drp_n_heads=4,
        scene_tokens=scene_tokens,
        image_height=image_size, image_width=image_size, patch_size=16,
        num_views=8, num_input_views=2,
        use_lseg=True, semantic_dim=32,
        # The official head widens to 16*16*64 per token (64 hidden channels); 8 channels
        # keep its last matrix at 1 M entries instead of 8 M here.
        semantic_hidden=8,
        dino=dino, lseg=lseg, clip=clip,
    ).validate()


def clone(cfg: SparConfig) -> SparConfig:
    return copy.deepcopy(cfg)
