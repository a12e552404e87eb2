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
import contextlib
import math
from typing import Any, Dict, Optional

import torch
import torch.nn as nn
import torch.nn.functional as F

# --------------------------------------------------------------------------------------------
# configurations: torch-free, in spar_convert.model_config (the converter uses them too)
# --------------------------------------------------------------------------------------------

from spar_convert.model_config import (  # noqa: E402,F401
    backbone_config, backbone_configs, resolve_config)


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


_INIT_FUNCTIONS = ("uniform_", "normal_", "trunc_normal_", "constant_", "ones_", "zeros_", "eye_",
                   "dirac_", "xavier_uniform_", "xavier_normal_", "kaiming_uniform_", "kaiming_normal_",
                   "orthogonal_", "sparse_")


@contextlib.contextmanager
def no_initial_values(dtype: Optional[torch.dtype] = None):
    """Modules built inside skip torch.nn.init's initial values (their parameters keep the
    uninitialized storage torch.empty gives), parameters made in ``dtype`` when given: for a
    model whose every tensor is then overwritten (load_state_dict(strict=True), randomize_).
    A full-size model spends ~5 s drawing initial values nobody reads and ~6 s converting
    them to float64; untouched storage costs nothing until it is written once."""
    import torch.nn.init as init
    saved = {name: getattr(init, name) for name in _INIT_FUNCTIONS}
    saved_dtype = torch.get_default_dtype()
    try:
        for name in _INIT_FUNCTIONS:
            setattr(init, name, lambda tensor, *args, **kwargs: tensor)
        if dtype is not None:
            torch.set_default_dtype(dtype)
        yield
    finally:
        for name, fn in saved.items():
            setattr(init, name, fn)
        torch.set_default_dtype(saved_dtype)


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
