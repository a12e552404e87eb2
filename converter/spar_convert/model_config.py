#!/usr/bin/python3
"""Model configuration of SPAR and its backbones, without torch (standard library only).

Shared by the converter (``spar_convert``, which must run without PyTorch) and the PyTorch
reference (``spar_reference.config`` and ``spar_reference.backbones`` re-export these names).

* ``backbone_config(name, preset)`` / ``backbone_configs`` / ``resolve_config(name, cfg)``: the
  size dictionaries of the backbones ``dino``, ``lseg``, ``clip`` (presets ``full``, ``tiny``).
* ``SparConfig``: every size SPAR needs; presets ``full()`` (official configs/spar/spar.yaml)
  and ``tiny()``; ``get_config(name_or_path)``; ``SparConfig.from_file`` reads the official
  YAML or the flat JSON/YAML that ``SparConfig.to_dict()`` / ``save`` write.

SparConfig
----------

Two presets:
  * ``full``: the values of the official ``configs/spar/spar.yaml`` (D=768, 12 heads of 64,
    pose encoder 12 layers, scene encoder 8, decoder 12, CV-DRP 4, 768 scene tokens,
    256x256 images, patch 16, 8 views, 512-d LSeg features).
  * ``tiny``: a test-sized model with the same code paths (D=64, 2 heads of 32, 2 layers per
    stack, 16 scene tokens, 128x128 images, patch 16, DINO width 64 == D).

``SparConfig.from_file(path)`` reads YAML or JSON, either in the official structure
(``model: {transformer: {d: ...}, ...}``, ``training: {...}``) or as the flat field dict that
``SparConfig.to_dict()`` writes.

The backbone sub-configurations live under the reserved keys ``dino``, ``lseg`` and ``clip``;
their fields belong to the backbone modules (``dino_v3.py``, ``lseg.py``, ``clip_text.py``).
The presets put in them only the sizes SPAR itself depends on (DINO width == D, LSeg feature
dim == ``semantic_dim``), plus the usual architecture numbers as a starting point.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import os
from dataclasses import dataclass, field
from typing import Any, Dict, Optional, Tuple

# --------------------------------------------------------------------------------------------
# configurations
# --------------------------------------------------------------------------------------------

_DINO_FULL = {
    # dinov3/hub/backbones.py: dinov3_vitb16
    "arch": "vitb16",
    "embed_dim": 768,
    "depth": 12,
    "num_heads": 12,
    "patch_size": 16,
    "n_storage_tokens": 4,
    "ffn_ratio": 4.0,
    "in_chans": 3,
    "rope_base": 100.0,               # pos_embed_rope_base
    "rope_normalize_coords": "separate",
    "layerscale_init": 1e-5,
    "ln_eps": 1e-5,                   # norm_layer "layernormbf16" = LayerNorm(eps=1e-5)
    "qkv_bias": True,
    "mask_k_bias": True,
    "proj_bias": True,
    "ffn_bias": True,
    # SPAR's DINOv3FeatureExtractor (model/dino_v3.py): ImageNet normalisation
    "mean": [0.485, 0.456, 0.406],
    "std": [0.229, 0.224, 0.225],
}

_DINO_TINY = dict(_DINO_FULL, arch="tiny", embed_dim=64, depth=2, num_heads=2)

_LSEG_FULL = {
    # lang-seg modules/models/lseg_net.py + lseg_vit.py, backbone clip_vitl16_384
    "backbone": "clip_vitl16_384",
    "width": 1024,                    # timm vit_large_patch16_384
    "depth": 24,
    "num_heads": 16,
    "mlp_ratio": 4.0,
    "patch_size": 16,
    "ln_eps": 1e-6,                   # timm ViT LayerNorm eps
    "pretrain_img_size": 384,         # learned position embeddings for a 24x24 grid
    "num_classes": 1000,              # timm classifier head (in the checkpoint, unused)
    "hooks": [5, 11, 17, 23],
    "reassemble": [256, 512, 1024, 1024],
    "features": 256,
    "feature_dim": 512,               # out_c of scratch.head1
    "use_bn": True,                   # LSegNet forces use_bn=True
    "readout": "project",
    # what SPAR feeds LSeg: images in [0,1] without any normalisation ("none");
    # LSeg itself was trained on Normalize(mean=0.5, std=0.5) inputs ("lseg")
    "input_norm": "none",
}

_LSEG_TINY = dict(_LSEG_FULL, backbone="tiny", width=64, depth=4, num_heads=2,
                  pretrain_img_size=64, num_classes=10, hooks=[0, 1, 2, 3],
                  reassemble=[16, 32, 64, 64], features=16, feature_dim=32)

_CLIP_FULL = {
    # openai/CLIP clip/model.py, ViT-B/32 text transformer
    "width": 512,
    "layers": 12,
    "heads": 8,
    "context_length": 77,
    "vocab_size": 49408,
    "embed_dim": 512,
    "ln_eps": 1e-5,
}

_CLIP_TINY = dict(_CLIP_FULL, width=64, layers=2, heads=2, embed_dim=32)

_PRESETS = {
    "dino": {"full": _DINO_FULL, "tiny": _DINO_TINY},
    "lseg": {"full": _LSEG_FULL, "tiny": _LSEG_TINY},
    "clip": {"full": _CLIP_FULL, "tiny": _CLIP_TINY},
}


def backbone_config(name: str, preset: str = "full") -> Dict[str, Any]:
    """A fresh copy of the size dictionary of backbone ``name`` (dino, lseg, clip)."""
    if name not in _PRESETS:
        raise KeyError(f"unknown backbone {name!r}; one of {sorted(_PRESETS)}")
    if preset not in _PRESETS[name]:
        raise KeyError(f"unknown preset {preset!r}; one of {sorted(_PRESETS[name])}")
    return copy.deepcopy(_PRESETS[name][preset])


def backbone_configs(preset: str = "full") -> Dict[str, Dict[str, Any]]:
    """{"dino": ..., "lseg": ..., "clip": ...} for one preset."""
    return {n: backbone_config(n, preset) for n in _PRESETS}


def resolve_config(name: str, cfg: Optional[Dict[str, Any]]) -> Dict[str, Any]:
    """Complete a partial dictionary: the official values for options, sizes derived from
    the sizes given (so a dictionary with only widths and depths is enough)."""
    cfg = dict(cfg or {})
    # a dictionary naming the tiny test model ("arch"/"backbone": "tiny") starts from the tiny
    # preset (small position-embedding grid and classifier), anything else from the full one
    tag = cfg.get("arch", cfg.get("backbone", cfg.get("preset")))
    out = backbone_config(name, "tiny" if tag == "tiny" else "full")
    cfg.pop("preset", None)
    if name == "dino":
        if "width" in cfg and "embed_dim" not in cfg:
            cfg["embed_dim"] = cfg["width"]
        cfg.pop("width", None)
        out.update(cfg)
    elif name == "lseg":
        if "out_dim" in cfg and "feature_dim" not in cfg:
            cfg["feature_dim"] = cfg["out_dim"]
        cfg.pop("out_dim", None)
        out.update(cfg)
        w, d = int(out["width"]), int(out["depth"])
        if "hooks" not in cfg:
            # [5, 11, 17, 23] for 24 layers
            out["hooks"] = [d // 4 - 1, d // 2 - 1, 3 * d // 4 - 1, d - 1] if d >= 4 else list(range(4))
        if "reassemble" not in cfg:
            # [256, 512, 1024, 1024] for width 1024
            out["reassemble"] = [w // 4, w // 2, w, w]
    elif name == "clip":
        out.update(cfg)
    else:
        raise KeyError(name)
    return out


# --------------------------------------------------------------------------------------------
# SPAR
# --------------------------------------------------------------------------------------------



def _backbone(name: str, preset: str) -> Dict[str, Any]:
    return backbone_config(name, preset)


def _full_dino() -> Dict[str, Any]:
    return _backbone("dino", "full")


def _full_lseg() -> Dict[str, Any]:
    return _backbone("lseg", "full")


def _full_clip() -> Dict[str, Any]:
    return _backbone("clip", "full")


@dataclass
class SparConfig:
    # transformer width and heads (model.transformer.d / d_head)
    d: int = 768
    d_head: int = 64
    # layers per stack
    encoder_n_layer: int = 12        # pose encoder  (transformer_encoder)
    encoder_geom_n_layer: int = 8    # scene encoder (transformer_encoder_geom)
    decoder_n_layer: int = 12        # renderer      (transformer_decoder)
    cv_drp_n_layer: int = 4          # CV-DRP blocks (cv_drp.estimator.transformer_layers)
    cv_drp_n_heads: int = 12         # CV-DRP heads: head dim = d // cv_drp_n_heads
    # tokens
    scene_tokens: int = 768          # model.scene_latent.length
    pose_tokens: int = 1             # model.pose_latent.length (the official forward asserts 1)
    # images
    image_height: int = 256
    image_width: int = 256
    patch_size: int = 16
    image_channels: int = 3
    ray_channels: int = 6
    # views (training.num_views; the official evaluation fixes 8 in all)
    num_views: int = 8
    num_input_views: int = 2
    # semantic branch
    use_lseg: bool = True            # official: true iff model.lseg.checkpoint_path is set
    semantic_dim: int = 512          # model.lseg.feature_dim
    semantic_hidden: int = 64        # d_semantic_hidden, hard-coded in the official code
    semantic_loss_weight: float = 0.1  # >0 puts the semantic queries into the decoder
    # options of the official code
    use_qk_norm: bool = True
    input_with_pe: bool = True
    canonical: str = "middle"        # model.pose_latent.canonical ("first" | "middle")
    pose_representation: str = "6d"  # model.pose_latent.representation ("6d" | "quat")
    mask_threshold: float = 0.5
    input_masking_mode: str = "soft_with_pe"  # | zero_out | learnable_indicator | none
    plucker_norm_mode: str = "none"  # | per_scene | learnable
    # backbones (fields owned by the backbone modules)
    dino: Dict[str, Any] = field(default_factory=_full_dino)
    lseg: Dict[str, Any] = field(default_factory=_full_lseg)
    clip: Dict[str, Any] = field(default_factory=_full_clip)

    # ------------------------------------------------------------------ derived sizes
    @property
    def n_heads(self) -> int:
        return self.d // self.d_head

    @property
    def cv_drp_head_dim(self) -> int:
        return self.d // self.cv_drp_n_heads

    @property
    def image_size(self) -> int:
        assert self.image_height == self.image_width
        return self.image_height

    @property
    def patches_h(self) -> int:
        return self.image_height // self.patch_size

    @property
    def patches_w(self) -> int:
        return self.image_width // self.patch_size

    @property
    def tokens_per_view(self) -> int:
        return self.patches_h * self.patches_w

    @property
    def dino_width(self) -> int:
        return int(self.dino.get("embed_dim", self.dino.get("width", self.d)))

    @property
    def semantic_decoding(self) -> bool:
        """Official ``enable_semantic_feature_supervision``: the semantic queries take part in
        the decoder (and change the RGB result through attention) only when this is true."""
        return self.use_lseg and self.semantic_loss_weight > 0.0

    def validate(self) -> "SparConfig":
        assert self.d % self.d_head == 0, "d must be a multiple of d_head"
        assert self.d % self.cv_drp_n_heads == 0, "d must be a multiple of cv_drp_n_heads"
        assert self.d % 8 == 0, "the sin-cos codes split D into quarters of even size"
        assert self.image_height > 0 and self.image_width > 0 and \
            self.image_height % self.patch_size == 0 and self.image_width % self.patch_size == 0, \
            "image size %dx%d is not a multiple of the patch size %d" % (
                self.image_height, self.image_width, self.patch_size)
        # CV-DRP decoder upsamples by exactly 16 (4 stride-2 transposed convolutions).
        assert self.patch_size == 16, "CV-DRP's decoder assumes patch size 16"
        # CV-DRP concatenates DINO, image and ray tokens raw: DINO width must be D.
        assert self.dino_width == self.d, "DINO width must equal D (CV-DRP concatenates raw)"
        # ... token by token: one DINOv3 patch per SPAR patch.
        assert int(self.dino.get("patch_size", self.patch_size)) == self.patch_size, \
            "DINO patch size must equal patch_size (CV-DRP pairs their tokens one to one)"
        assert self.canonical in ("first", "middle")
        assert self.pose_representation in ("6d", "quat")
        assert self.input_masking_mode in ("soft_with_pe", "zero_out", "learnable_indicator", "none")
        assert self.plucker_norm_mode in ("none", "per_scene", "learnable")
        assert self.pose_tokens == 1, "the official forward asserts one camera token per view"
        if "feature_dim" in self.lseg and int(self.lseg["feature_dim"]) != self.semantic_dim:
            raise ValueError("semantic_dim must equal lseg.feature_dim")
        if self.use_lseg:
            # LSeg's 4th hook halves its H/16 grid (stride-2 conv) and the fusion doubles it
            # back: H and W multiples of 32 (which also pools H/2 by 8 into one semantic token
            # per 16x16 pixels).
            assert self.image_height % 32 == 0 and self.image_width % 32 == 0, \
                "image size %dx%d is not a multiple of 32 (LSeg, semantic branch)" % (
                    self.image_height, self.image_width)
        return self

    # ------------------------------------------------------------------ (de)serialisation
    def to_dict(self) -> Dict[str, Any]:
        return copy.deepcopy(dataclasses.asdict(self))

    @classmethod
    def from_dict(cls, d: Dict[str, Any]) -> "SparConfig":
        if "model" in d:
            return cls.from_official(d)
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown SparConfig fields: {sorted(unknown)}")
        return cls(**copy.deepcopy(d)).validate()

    @classmethod
    def from_official(cls, y: Dict[str, Any]) -> "SparConfig":
        """Build from the structure of the official YAML (configs/spar/spar.yaml)."""
        m = y.get("model", {}) or {}
        t = y.get("training", {}) or {}
        tr = m.get("transformer", {}) or {}
        it = m.get("image_tokenizer", {}) or {}
        ti = m.get("target_image", {}) or {}
        cv = m.get("cv_drp", {}) or {}
        ls = m.get("lseg", {}) or {}
        dn = m.get("dino_v3", {}) or {}
        pl = m.get("pose_latent", {}) or {}
        im = m.get("input_masking", {}) or {}
        pn = m.get("plucker_normalization", {}) or {}
        c = cls()
        c.d = int(tr.get("d", c.d))
        c.d_head = int(tr.get("d_head", c.d_head))
        c.encoder_n_layer = int(tr.get("encoder_n_layer", c.encoder_n_layer))
        c.encoder_geom_n_layer = int(tr.get("encoder_geom_n_layer", c.encoder_geom_n_layer))
        c.decoder_n_layer = int(tr.get("decoder_n_layer", c.decoder_n_layer))
        c.use_qk_norm = bool(tr.get("use_qk_norm", False))  # official default is False
        c.cv_drp_n_layer = int(cv.get("vit_n_layers", 4))
        c.cv_drp_n_heads = int(cv.get("vit_n_heads", 12))
        c.mask_threshold = float(cv.get("mask_threshold", 0.5))
        c.scene_tokens = int((m.get("scene_latent", {}) or {}).get("length", c.scene_tokens))
        c.pose_tokens = int(pl.get("length", 1))
        c.canonical = str(pl.get("canonical", "first"))  # official default is "first"
        c.pose_representation = str(pl.get("representation", "6d"))
        c.patch_size = int(ti.get("patch_size", it.get("patch_size", c.patch_size)))
        if int(it.get("patch_size", c.patch_size)) != c.patch_size:
            raise ValueError("image_tokenizer.patch_size and target_image.patch_size differ")
        c.image_height, c.image_width = official_image_size(y) or (c.image_height, c.image_width)
        c.image_channels = int(it.get("in_channels", 3))
        c.ray_channels = int(ti.get("in_channels", 6))
        c.input_with_pe = bool(m.get("input_with_pe", True))
        c.input_masking_mode = str(im.get("mode", m.get("input_masking_mode", "soft_with_pe")))
        c.plucker_norm_mode = str(pn.get("mode", "none"))
        c.use_lseg = ls.get("checkpoint_path") is not None
        c.semantic_dim = int(ls.get("feature_dim", 512))
        c.semantic_loss_weight = float(t.get("semantic_loss_weight", 0.1))
        c.num_views = int(t.get("num_views", c.num_views))
        c.num_input_views = int(t.get("num_input_views", c.num_input_views))
        c.dino = _full_dino()
        c.dino["embed_dim"] = int(dn.get("embed_dim", 768))
        c.dino["arch"] = str(dn.get("arch", "vitb16"))
        c.lseg = _full_lseg()
        c.lseg["feature_dim"] = c.semantic_dim
        # carry through any extra backbone fields given under our reserved keys
        for key in ("dino", "lseg", "clip"):
            if isinstance(y.get(key), dict):
                getattr(c, key).update(copy.deepcopy(y[key]))
        return c.validate()

    @classmethod
    def from_file(cls, path: str) -> "SparConfig":
        return cls.from_dict(read_config_file(path))

    def save(self, path: str) -> None:
        with open(path, "w", encoding="utf-8") as f:
            json.dump(self.to_dict(), f, indent=2, sort_keys=True)


def read_config_file(path: str) -> Dict[str, Any]:
    """The parsed YAML or JSON of a configuration file (``SparConfig.from_dict`` reads it)."""
    with open(path, "r", encoding="utf-8") as f:
        text = f.read()
    if os.path.splitext(path)[1].lower() == ".json":
        return json.loads(text)
    import yaml
    return yaml.safe_load(text)


def official_image_size(y: Dict[str, Any]) -> Optional[Tuple[int, int]]:
    """(height, width) the official YAML trains at, or None when it names no size.

    spar.yaml states it twice: ``model.target_image.height`` / ``width`` (the rendered views)
    and ``model.image_tokenizer.image_size`` (square inputs); a side that target_image leaves
    out is image_size. Both given and different is a configuration the official code could
    not run (the ray and image tokens of a view would not line up), so it is refused."""
    m = y.get("model", {}) or {}
    it = m.get("image_tokenizer", {}) or {}
    ti = m.get("target_image", {}) or {}
    square = it.get("image_size")
    h, w = ti.get("height", square), ti.get("width", square)
    if h is None or w is None:
        return None
    if square is not None and (int(h), int(w)) != (int(square), int(square)):
        raise ValueError("image_tokenizer.image_size %s and target_image %sx%s differ"
                         % (square, h, w))
    return int(h), int(w)


def stated_image_size(data: Dict[str, Any]) -> Optional[Tuple[int, int]]:
    """(height, width) a configuration file's dictionary names, None when it names none (then
    ``SparConfig`` holds the official default 256x256, which may not be what the checkpoint
    was trained at). Official YAML structure or the flat ``SparConfig.to_dict()`` fields."""
    if not isinstance(data, dict):
        return None
    if "model" in data:
        return official_image_size(data)
    if "image_height" in data and "image_width" in data:
        return int(data["image_height"]), int(data["image_width"])
    return None


def full() -> SparConfig:
    """The official configs/spar/spar.yaml."""
    return SparConfig().validate()


def tiny() -> SparConfig:
    """Test-sized SPAR with every code path of the full model."""
    return SparConfig(
        d=64, d_head=32,
        encoder_n_layer=2, encoder_geom_n_layer=2, decoder_n_layer=2,
        cv_drp_n_layer=2, cv_drp_n_heads=2,
        scene_tokens=16,
        image_height=128, image_width=128, patch_size=16,
        num_views=5, num_input_views=3,
        use_lseg=True, semantic_dim=32,
        dino=_backbone("dino", "tiny"),
        lseg=_backbone("lseg", "tiny"),
        clip=_backbone("clip", "tiny"),
    ).validate()


PRESETS = {"full": full, "tiny": tiny}


def tensor_signature(cfg: SparConfig) -> Dict[str, Any]:
    """The tensor sizes that tell SPAR configurations apart: a few shapes ("name": shape, None
    for a tensor the configuration has not) and layer counts ("n:stack": layers)."""
    p, d = cfg.patch_size, cfg.d
    return {
        "scene_code": (cfg.scene_tokens, d),
        "image_tokenizer.1.weight": (d, cfg.image_channels * p * p),
        "n:transformer_encoder": cfg.encoder_n_layer,
        "n:transformer_encoder_geom": cfg.encoder_geom_n_layer,
        "n:transformer_decoder": cfg.decoder_n_layer,
        "n:cv_drp.estimator.transformer_layers": cfg.cv_drp_n_layer,
        "transformer_encoder.0.attn.q_norm.weight": (cfg.d_head,) if cfg.use_qk_norm else None,
        "semantic_proj.weight": (d, cfg.semantic_dim + 6) if cfg.use_lseg else None,
    }


def checkpoint_signature(shapes: Dict[str, Tuple[int, ...]], keys) -> Dict[str, Any]:
    """The same keys as tensor_signature, read from a checkpoint's SPAR tensors (name -> shape)."""
    sig: Dict[str, Any] = {}
    for k in keys:
        if k.startswith("n:"):
            pre = k[2:] + "."
            idx = {int(x[len(pre):].split(".")[0]) for x in shapes
                   if x.startswith(pre) and x[len(pre):].split(".")[0].isdigit()}
            sig[k] = len(idx)
        else:
            sig[k] = tuple(shapes[k]) if k in shapes else None
    return sig


def matching_preset(shapes: Dict[str, Tuple[int, ...]]) -> Optional[str]:
    """The preset whose tensor sizes a checkpoint without a configuration has, or None.

    The one rule of both tools (spar-convert, spar-reference) for such a checkpoint: a preset it
    matches is its configuration, image size included (tiny: 128x128); otherwise the sizes come
    from its tensors and the image size, which no tensor holds, is the official 256x256."""
    for name, make in PRESETS.items():
        want = tensor_signature(make())
        if checkpoint_signature(shapes, want) == want:
            return name
    return None


def get_config(name_or_path: str) -> SparConfig:
    """A preset name (``full``, ``tiny``) or a YAML/JSON path."""
    if name_or_path in PRESETS:
        return PRESETS[name_or_path]()
    return SparConfig.from_file(name_or_path)
