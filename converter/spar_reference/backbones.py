#!/usr/bin/python3
"""Shared pieces of the three backbone references (DINOv3, LSeg, CLIP text).

* ``backbone_config(name, preset)``: the size dictionaries for ``dino``, ``lseg`` and ``clip``
  (presets ``full`` and ``tiny``); ``resolve_config(name, cfg)`` fills the fields a partial
  dictionary leaves out (derived from the sizes it gives, e.g. LSeg hooks from the depth).
* ``randomize_(module, seed, perturb)``: deterministic random weights.  Without ``perturb`` the
  values follow the official initialisations (biases 0, LayerNorm (1, 0), LayerScale 1e-5,
  BatchNorm statistics (0, 1)); with ``perturb`` every one of those is random too, so a test can
  see a dropped bias, a LayerScale, a BatchNorm statistic or a masked k bias.
* ``attention(q, k, v, mask)``: plain softmax attention in the dtype of its inputs (so a module
  converted with ``.double()`` runs entirely in float64).

Key names and shapes follow the official state_dicts; see each module's docstring.
"""
import copy
import math
from typing import Any, Dict, Optional

import torch
import torch.nn as nn
import torch.nn.functional as F

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
# shared math
# --------------------------------------------------------------------------------------------

def attention(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor,
              mask: Optional[torch.Tensor] = None) -> torch.Tensor:
    """softmax(q k^T / sqrt(dh) + mask) v over [..., N, dh] tensors, in the inputs' dtype."""
    scale = 1.0 / math.sqrt(q.shape[-1])
    logits = torch.matmul(q, k.transpose(-2, -1)) * scale
    if mask is not None:
        logits = logits + mask.to(logits.dtype)
    return torch.matmul(torch.softmax(logits, dim=-1), v)


def strip_prefix(state_dict: Dict[str, Any], prefix: str, keep_others: bool = False) -> Dict[str, Any]:
    """The entries under ``prefix`` with it removed (others dropped unless ``keep_others``)."""
    out = {}
    for k, v in state_dict.items():
        if k.startswith(prefix):
            out[k[len(prefix):]] = v
        elif keep_others:
            out[k] = v
    return out


def add_prefix(state_dict: Dict[str, Any], prefix: str) -> Dict[str, Any]:
    return {prefix + k: v for k, v in state_dict.items()}


# --------------------------------------------------------------------------------------------
# random weights
# --------------------------------------------------------------------------------------------

def _normal(g: torch.Generator, t: torch.Tensor, std: float, mean: float = 0.0) -> None:
    with torch.no_grad():
        t.copy_((torch.randn(t.shape, generator=g) * std + mean).to(t.dtype))


def _uniform(g: torch.Generator, t: torch.Tensor, lo: float, hi: float) -> None:
    with torch.no_grad():
        t.copy_((torch.rand(t.shape, generator=g) * (hi - lo) + lo).to(t.dtype))


def _fill(t: torch.Tensor, value: float) -> None:
    with torch.no_grad():
        t.fill_(value)


def randomize_(module: nn.Module, seed: int = 0, perturb: bool = False) -> nn.Module:
    """Deterministic random weights for every parameter and float buffer of ``module``.

    Matrices and convolution kernels ~ N(0, 1/fan_in) (activations stay O(1) at any width).
    Biases, LayerNorm and BatchNorm affine parameters, BatchNorm running statistics and
    LayerScale gammas take their official initial values, or random ones with ``perturb``.
    Modules may define ``_randomize_own_(g, perturb)`` for their direct parameters and for
    fixed buffers (RoPE periods, the k-bias mask); other direct parameters (class tokens,
    position embeddings, projections) ~ N(0, 0.02), or N(0, 0.5) / N(0, 1/rows) for
    names listed in the module's ``_matrix_params``.  The same seed gives the same values in
    float32 and float64 (they are drawn in float32 and cast)."""
    g = torch.Generator().manual_seed(int(seed))
    bias_std = 0.2 if perturb else 0.0
    for _, m in module.named_modules():
        if any(p.is_meta for p in m.parameters(recurse=False)):
            continue
        if isinstance(m, (nn.Linear, nn.Conv2d, nn.ConvTranspose2d)):
            w = m.weight
            if isinstance(m, nn.ConvTranspose2d):
                fan_in = w.shape[0] * w.shape[2] * w.shape[3] // max(1, (m.stride[0] * m.stride[1]))
            else:
                fan_in = w[0].numel()
            _normal(g, w, 1.0 / math.sqrt(max(1, fan_in)))
            if m.bias is not None:
                _normal(g, m.bias, bias_std)
        elif isinstance(m, nn.LayerNorm):
            if m.weight is not None:
                _normal(g, m.weight, bias_std, 1.0)
            if m.bias is not None:
                _normal(g, m.bias, bias_std)
        elif isinstance(m, nn.BatchNorm2d):
            _normal(g, m.weight, bias_std, 1.0)
            _normal(g, m.bias, bias_std)
            _normal(g, m.running_mean, bias_std)
            if perturb:
                _uniform(g, m.running_var, 0.5, 2.0)
            else:
                _fill(m.running_var, 1.0)
        elif isinstance(m, nn.Embedding):
            _normal(g, m.weight, 1.0 if perturb else 0.02)
        if hasattr(m, "_randomize_own_"):
            m._randomize_own_(g, perturb)
        elif not isinstance(m, (nn.Linear, nn.Conv2d, nn.ConvTranspose2d, nn.LayerNorm,
                                nn.BatchNorm2d, nn.Embedding)):
            matrices = getattr(m, "_matrix_params", ())
            for pname, p in m.named_parameters(recurse=False):
                if pname in matrices:
                    _normal(g, p, 1.0 / math.sqrt(p.shape[0]))
                else:
                    _normal(g, p, 0.5 if perturb else 0.02)
    return module
