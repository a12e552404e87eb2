#!/usr/bin/python3
"""One pre-norm transformer block for every stack of the reference.

SPAR's stacks (pose encoder, scene encoder, decoder, CV-DRP) use the official
``QK_Norm_TransformerBlock`` defaults of ``model/transformer.py``: LayerNorm without bias
(eps 1e-5), ``to_qkv`` without bias, QK-norm (RMSNorm over the head dim, weight, eps 1e-5,
computed in fp32), scale 1/sqrt(dh), ``fc`` without bias, MLP D -> 4D -> D without biases and
exact (erf) GELU. Key names are the official ones:

    norm1.weight  attn.to_qkv.weight  attn.q_norm.weight  attn.k_norm.weight  attn.fc.weight
    norm2.weight  mlp.mlp.0.weight  mlp.mlp.2.weight

The backbones reuse the block with other options: biases, LayerScale (``ls1.gamma``,
``ls2.gamma``), a RoPE hook applied to q and k, a causal or additive attention mask, a masked
k bias (DINOv3), QuickGELU (CLIP). Renaming their checkpoint keys to these module names is
the backbone code's business.

Torch 1.13 (Debian) has neither ``nn.LayerNorm(bias=False)`` nor
``F.scaled_dot_product_attention``: both are written out here.
"""

from __future__ import annotations

import math
from typing import Callable, Optional, Tuple

import torch
import torch.nn as nn
import torch.nn.functional as F


def compute_dtype(dtype: torch.dtype) -> torch.dtype:
    """The dtype of a computation the official code does in fp32 on purpose: fp32 for
    fp32/fp16/bf16 inputs, but float64 stays float64 (float64 reference mode)."""
    return torch.float64 if dtype == torch.float64 else torch.float32


class LayerNorm(nn.Module):
    """LayerNorm over the last dim with a weight and optionally a bias (``nn.LayerNorm(d,
    bias=False)`` of torch >= 2.1 has the same state_dict: ``weight`` only)."""

    def __init__(self, dim: int, eps: float = 1e-5, bias: bool = True):
        super().__init__()
        self.dim = dim
        self.eps = eps
        self.weight = nn.Parameter(torch.ones(dim))
        if bias:
            self.bias = nn.Parameter(torch.zeros(dim))
        else:
            self.register_parameter("bias", None)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.layer_norm(x, (self.dim,), self.weight, self.bias, self.eps)


class RMSNorm(nn.Module):
    """Official RMSNorm: x * rsqrt(mean(x^2) + eps) in fp32, cast back, times weight."""

    def __init__(self, dim: int, eps: float = 1e-5):
        super().__init__()
        self.eps = eps
        self.weight = nn.Parameter(torch.ones(dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        orig = x.dtype
        xf = x.to(compute_dtype(orig))  # official: x.float(); float64 stays float64
        y = xf * torch.rsqrt(xf.pow(2).mean(-1, keepdim=True) + self.eps)
        return y.to(orig) * self.weight.to(orig)


class QuickGELU(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * torch.sigmoid(1.702 * x)


def make_activation(name: str) -> nn.Module:
    if name == "gelu":
        return nn.GELU()                      # exact erf GELU (official nn.GELU())
    if name == "gelu_tanh":
        return nn.GELU(approximate="tanh")
    if name == "quick_gelu":
        return QuickGELU()
    if name == "silu":
        return nn.SiLU()
    raise ValueError(f"unknown activation {name}")


class MLP(nn.Module):
    """Official MLP: ``mlp`` = Sequential(Linear, act, Linear, Dropout) -> keys mlp.0, mlp.2."""

    def __init__(self, dim: int, hidden: int, bias: bool = False, activation: str = "gelu"):
        super().__init__()
        self.mlp = nn.Sequential(
            nn.Linear(dim, hidden, bias=bias),
            make_activation(activation),
            nn.Linear(hidden, dim, bias=bias),
            nn.Dropout(0.0),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.mlp(x)


RopeHook = Callable[[torch.Tensor, torch.Tensor], Tuple[torch.Tensor, torch.Tensor]]


def attention(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor,
              attn_mask: Optional[torch.Tensor] = None, causal: bool = False) -> torch.Tensor:
    """Softmax attention. q, k, v: [B, heads, L, dh]. attn_mask: additive (float) or boolean
    (True = attend), broadcast to [B, heads, Lq, Lk]. Scale 1/sqrt(dh)."""
    scale = 1.0 / math.sqrt(q.shape[-1])
    logits = torch.matmul(q, k.transpose(-1, -2)) * scale
    if causal:
        lq, lk = logits.shape[-2:]
        keep = torch.ones(lq, lk, dtype=torch.bool, device=q.device).tril(diagonal=lk - lq)
        logits = logits.masked_fill(~keep, float("-inf"))
    if attn_mask is not None:
        if attn_mask.dtype == torch.bool:
            logits = logits.masked_fill(~attn_mask, float("-inf"))
        else:
            logits = logits + attn_mask.to(logits.dtype)
    return torch.matmul(torch.softmax(logits, dim=-1), v)


class SelfAttention(nn.Module):
    """Official ``QK_Norm_SelfAttention``: to_qkv -> split q|k|v -> heads '(nh dh)' ->
    optional per-head RMSNorm of q and k -> attention -> fc."""

    def __init__(self, dim: int, head_dim: int, qkv_bias: bool = False, fc_bias: bool = False,
                 qk_norm: bool = True, qk_norm_eps: float = 1e-5, mask_k_bias: bool = False):
        super().__init__()
        assert dim % head_dim == 0
        self.dim = dim
        self.head_dim = head_dim
        self.num_heads = dim // head_dim
        self.use_qk_norm = qk_norm
        self.mask_k_bias = mask_k_bias
        self.to_qkv = nn.Linear(dim, 3 * dim, bias=qkv_bias)
        self.fc = nn.Linear(dim, dim, bias=fc_bias)
        if qk_norm:
            self.q_norm = RMSNorm(head_dim, eps=qk_norm_eps)
            self.k_norm = RMSNorm(head_dim, eps=qk_norm_eps)

    def forward(self, x: torch.Tensor, attn_mask: Optional[torch.Tensor] = None,
                causal: bool = False, rope: Optional[RopeHook] = None) -> torch.Tensor:
        b, l, _ = x.shape
        bias = self.to_qkv.bias
        if bias is not None and self.mask_k_bias:
            # DINOv3: the k part of the qkv bias is masked out (multiplied by 0).
            keep = torch.ones_like(bias)
            keep[self.dim:2 * self.dim] = 0
            bias = bias * keep
        qkv = F.linear(x, self.to_qkv.weight, bias)
        q, k, v = qkv.chunk(3, dim=-1)
        q, k, v = (t.reshape(b, l, self.num_heads, self.head_dim) for t in (q, k, v))
        if self.use_qk_norm:
            q = self.q_norm(q)
            k = self.k_norm(k)
        q, k, v = (t.transpose(1, 2) for t in (q, k, v))  # [b, nh, l, dh]
        if rope is not None:
            q, k = rope(q, k)
        y = attention(q, k, v, attn_mask=attn_mask, causal=causal)
        y = y.transpose(1, 2).reshape(b, l, self.dim)
        return self.fc(y)


class LayerScale(nn.Module):
    def __init__(self, dim: int, init: float = 1e-5):
        super().__init__()
        self.gamma = nn.Parameter(torch.full((dim,), float(init)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.gamma


class Block(nn.Module):
    """Pre-norm block: x += ls1(attn(norm1(x))); x += ls2(mlp(norm2(x))).

    Defaults are SPAR's (official ``QK_Norm_TransformerBlock(d, d_head, use_qk_norm=True)``).
    """

    def __init__(self, dim: int, head_dim: int, *, ln_bias: bool = False, ln_eps: float = 1e-5,
                 qkv_bias: bool = False, fc_bias: bool = False, mlp_bias: bool = False,
                 mlp_ratio: float = 4.0, mlp_hidden: Optional[int] = None,
                 qk_norm: bool = True, layerscale: Optional[float] = None,
                 activation: str = "gelu", causal: bool = False, mask_k_bias: bool = False):
        super().__init__()
        self.causal = causal
        self.norm1 = LayerNorm(dim, eps=ln_eps, bias=ln_bias)
        self.attn = SelfAttention(dim, head_dim, qkv_bias=qkv_bias, fc_bias=fc_bias,
                                  qk_norm=qk_norm, mask_k_bias=mask_k_bias)
        self.norm2 = LayerNorm(dim, eps=ln_eps, bias=ln_bias)
        hidden = mlp_hidden if mlp_hidden is not None else int(dim * mlp_ratio)
        self.mlp = MLP(dim, hidden, bias=mlp_bias, activation=activation)
        if layerscale is not None:
            self.ls1 = LayerScale(dim, layerscale)
            self.ls2 = LayerScale(dim, layerscale)
        else:
            self.ls1 = None
            self.ls2 = None

    def forward(self, x: torch.Tensor, attn_mask: Optional[torch.Tensor] = None,
                rope: Optional[RopeHook] = None) -> torch.Tensor:
        a = self.attn(self.norm1(x), attn_mask=attn_mask, causal=self.causal, rope=rope)
        if self.ls1 is not None:
            a = self.ls1(a)
        x = x + a
        m = self.mlp(self.norm2(x))
        if self.ls2 is not None:
            m = self.ls2(m)
        return x + m


def spar_block(d: int, d_head: int, use_qk_norm: bool = True) -> Block:
    """The block of every SPAR stack (official QK_Norm_TransformerBlock defaults)."""
    return Block(d, d_head, qk_norm=use_qk_norm)
