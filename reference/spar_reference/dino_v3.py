#!/usr/bin/python3
"""DINOv3 ViT reference (the frozen backbone of SPAR's CV-DRP), float32 or float64.

``DinoV3Backbone(cfg)`` has the key layout of the released ``dinov3_vitb16_pretrain_*.pth``
(a bare state_dict, loaded by ``dinov3.hub.backbones.dinov3_vitb16`` with strict=True)::

    cls_token [1,1,D]  storage_tokens [1,4,D]  mask_token [1,D]
    patch_embed.proj.weight [D,3,16,16]  patch_embed.proj.bias [D]
    rope_embed.periods [D/heads/4]                       (persistent buffer)
    blocks.i.norm1.{weight,bias}
    blocks.i.attn.qkv.weight [3D,D]  .qkv.bias [3D]  .qkv.bias_mask [3D]   (buffer)
    blocks.i.attn.proj.{weight,bias}  blocks.i.ls1.gamma [D]
    blocks.i.norm2.{weight,bias}  blocks.i.mlp.fc1.{weight,bias}  blocks.i.mlp.fc2.{weight,bias}
    blocks.i.ls2.gamma [D]
    norm.{weight,bias}

``DinoV3(cfg)`` is SPAR's ``DINOv3FeatureExtractor`` (model/dino_v3.py): buffers ``mean``,
``std`` ([1,3,1,1], ImageNet) and the backbone as ``model``; in a SPAR training checkpoint
these are ``_dino_v3.mean``, ``_dino_v3.std``, ``_dino_v3.model.*``.

Forward, as the official code runs it in eval mode:
  x = (img - mean) / std  (bilinear resize to a multiple of the patch if needed)
  tokens = [cls, 4 storage tokens, conv16x16(x) patches]
  12 x: x += ls1 * proj(attn(LN1(x)));  x += ls2 * fc2(GELU(fc1(LN2(x))))
     qkv bias = bias * bias_mask (the released mask zeroes the k third);
     RoPE on q and k of the patch tokens only (prefix tokens untouched):
       coords = 2 * ((i + 0.5) / h) - 1 per axis ("separate"), periods = base^(2j / (dh/2)),
       j < dh/4, angles = 2 pi coord / period, [rows | cols] then tiled twice over dh,
       x * cos + rotate_half(x) * sin with rotate_half([a, b]) = [-b, a]
  patch tokens = LN(x)[:, 1 + 4:]    (LayerNorm eps 1e-5, exact erf GELU)

Differences from the official code, all numerically nil in float32: the RoPE sin/cos are
computed in the module's dtype (the official code fixes them to float32 even after
``.double()``), training-time coordinate jitter/rescale is not implemented (SPAR runs the
backbone in eval mode), and attention is written out instead of scaled_dot_product_attention.
"""
import math
from typing import Any, Dict, Optional, Tuple

import torch
import torch.nn as nn
import torch.nn.functional as F

from .backbones import attention, randomize_, resolve_config


class LayerScale(nn.Module):
    def __init__(self, dim: int, init_value: float, device=None):
        super().__init__()
        self.init_value = float(init_value)
        self.gamma = nn.Parameter(torch.full((dim,), self.init_value, device=device))

    def _randomize_own_(self, g: torch.Generator, perturb: bool) -> None:
        with torch.no_grad():
            if perturb:
                self.gamma.copy_((torch.rand(self.gamma.shape, generator=g) * 0.8 + 0.2).to(self.gamma.dtype))
            else:
                self.gamma.fill_(self.init_value)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.gamma


class LinearKMaskedBias(nn.Linear):
    """Linear whose bias is multiplied by the buffer ``bias_mask`` (1 for q and v, 0 for k)."""

    def __init__(self, in_features: int, out_features: int, bias: bool = True, device=None):
        super().__init__(in_features, out_features, bias=bias, device=device)
        assert out_features % 3 == 0
        if bias:
            self.register_buffer("bias_mask", self._mask(out_features, device))

    @staticmethod
    def _mask(o: int, device=None) -> torch.Tensor:
        m = torch.ones(o)
        m[o // 3: 2 * o // 3] = 0.0
        return m.to(device) if device is not None else m

    def _randomize_own_(self, g: torch.Generator, perturb: bool) -> None:
        if self.bias is not None:
            with torch.no_grad():
                self.bias_mask.copy_(self._mask(self.out_features).to(self.bias_mask.dtype))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b = None if self.bias is None else self.bias * self.bias_mask.to(self.bias.dtype)
        return F.linear(x, self.weight, b)


class RopePositionEmbedding(nn.Module):
    """Axial RoPE without learned weights; ``periods`` is a persistent buffer."""

    def __init__(self, embed_dim: int, num_heads: int, base: float, normalize_coords: str,
                 device=None):
        super().__init__()
        assert embed_dim % (4 * num_heads) == 0
        self.d_head = embed_dim // num_heads
        self.base = float(base)
        self.normalize_coords = normalize_coords
        self.register_buffer("periods", self._periods(device), persistent=True)

    def _periods(self, device=None) -> torch.Tensor:
        n = self.d_head // 4
        p = self.base ** (2 * torch.arange(n, dtype=torch.float32) / (self.d_head // 2))
        return p.to(device) if device is not None else p

    def _randomize_own_(self, g: torch.Generator, perturb: bool) -> None:
        with torch.no_grad():
            self.periods.copy_(self._periods().to(self.periods.dtype))

    def forward(self, H: int, W: int) -> Tuple[torch.Tensor, torch.Tensor]:
        dd = {"device": self.periods.device, "dtype": self.periods.dtype}
        if self.normalize_coords == "separate":
            ch = torch.arange(0.5, H, **dd) / H
            cw = torch.arange(0.5, W, **dd) / W
        elif self.normalize_coords == "max":
            ch = torch.arange(0.5, H, **dd) / max(H, W)
            cw = torch.arange(0.5, W, **dd) / max(H, W)
        elif self.normalize_coords == "min":
            ch = torch.arange(0.5, H, **dd) / min(H, W)
            cw = torch.arange(0.5, W, **dd) / min(H, W)
        else:
            raise ValueError(self.normalize_coords)
        coords = torch.stack(torch.meshgrid(ch, cw, indexing="ij"), dim=-1).flatten(0, 1)  # [HW, 2]
        coords = 2.0 * coords - 1.0
        angles = 2 * math.pi * coords[:, :, None] / self.periods[None, None, :]  # [HW, 2, dh/4]
        angles = angles.flatten(1, 2).tile(2)  # [HW, dh]: rows, cols, rows, cols
        return torch.sin(angles), torch.cos(angles)


def _rope_apply(x: torch.Tensor, sin: torch.Tensor, cos: torch.Tensor) -> torch.Tensor:
    x1, x2 = x.chunk(2, dim=-1)
    return x * cos + torch.cat([-x2, x1], dim=-1) * sin


class DinoSelfAttention(nn.Module):
    def __init__(self, dim: int, num_heads: int, qkv_bias: bool, proj_bias: bool,
                 mask_k_bias: bool, device=None):
        super().__init__()
        self.num_heads = num_heads
        if mask_k_bias:
            self.qkv = LinearKMaskedBias(dim, 3 * dim, bias=qkv_bias, device=device)
        else:
            self.qkv = nn.Linear(dim, 3 * dim, bias=qkv_bias, device=device)
        self.proj = nn.Linear(dim, dim, bias=proj_bias, device=device)

    def forward(self, x: torch.Tensor, rope: Optional[Tuple[torch.Tensor, torch.Tensor]]) -> torch.Tensor:
        B, N, C = x.shape
        qkv = self.qkv(x).reshape(B, N, 3, self.num_heads, C // self.num_heads)
        q, k, v = [t.transpose(1, 2) for t in torch.unbind(qkv, 2)]  # [B, heads, N, dh]
        if rope is not None:
            sin, cos = rope
            p = N - sin.shape[-2]
            q = torch.cat([q[:, :, :p], _rope_apply(q[:, :, p:], sin, cos)], dim=2)
            k = torch.cat([k[:, :, :p], _rope_apply(k[:, :, p:], sin, cos)], dim=2)
        o = attention(q, k, v)
        return self.proj(o.transpose(1, 2).reshape(B, N, C))


class DinoMlp(nn.Module):
    def __init__(self, dim: int, hidden: int, bias: bool, device=None):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden, bias=bias, device=device)
        self.act = nn.GELU()
        self.fc2 = nn.Linear(hidden, dim, bias=bias, device=device)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(self.act(self.fc1(x)))


class DinoBlock(nn.Module):
    def __init__(self, c: Dict[str, Any], device=None):
        super().__init__()
        dim = int(c["embed_dim"])
        eps = float(c["ln_eps"])
        self.norm1 = nn.LayerNorm(dim, eps=eps, device=device)
        self.attn = DinoSelfAttention(dim, int(c["num_heads"]), bool(c["qkv_bias"]),
                                      bool(c["proj_bias"]), bool(c["mask_k_bias"]), device=device)
        ls = c.get("layerscale_init")
        self.ls1 = LayerScale(dim, ls, device=device) if ls else nn.Identity()
        self.norm2 = nn.LayerNorm(dim, eps=eps, device=device)
        self.mlp = DinoMlp(dim, int(dim * float(c["ffn_ratio"])), bool(c["ffn_bias"]), device=device)
        self.ls2 = LayerScale(dim, ls, device=device) if ls else nn.Identity()

    def forward(self, x: torch.Tensor, rope) -> torch.Tensor:
        x = x + self.ls1(self.attn(self.norm1(x), rope))
        return x + self.ls2(self.mlp(self.norm2(x)))


class DinoPatchEmbed(nn.Module):
    def __init__(self, patch: int, in_chans: int, dim: int, device=None):
        super().__init__()
        self.proj = nn.Conv2d(in_chans, dim, kernel_size=patch, stride=patch, device=device)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj(x)  # [B, D, h, w]


class DinoV3Backbone(nn.Module):
    """DinoVisionTransformer as ``dinov3_vitb16`` builds it (sizes from ``cfg``)."""

    def __init__(self, cfg: Optional[Dict[str, Any]] = None, seed: int = 0, perturb: bool = False,
                 device=None):
        super().__init__()
        c = resolve_config("dino", cfg)
        self.cfg = c
        dim = int(c["embed_dim"])
        self.embed_dim = dim
        self.patch_size = int(c["patch_size"])
        self.n_storage_tokens = int(c["n_storage_tokens"])
        self.cls_token = nn.Parameter(torch.zeros(1, 1, dim, device=device))
        if self.n_storage_tokens > 0:
            self.storage_tokens = nn.Parameter(torch.zeros(1, self.n_storage_tokens, dim, device=device))
        self.mask_token = nn.Parameter(torch.zeros(1, dim, device=device))
        self.patch_embed = DinoPatchEmbed(self.patch_size, int(c["in_chans"]), dim, device=device)
        self.rope_embed = RopePositionEmbedding(dim, int(c["num_heads"]), float(c["rope_base"]),
                                                str(c["rope_normalize_coords"]), device=device)
        self.blocks = nn.ModuleList([DinoBlock(c, device=device) for _ in range(int(c["depth"]))])
        self.norm = nn.LayerNorm(dim, eps=float(c["ln_eps"]), device=device)
        if str(device) != "meta":
            randomize_(self, seed, perturb)
        self.eval()

    def forward_features(self, x: torch.Tensor) -> Dict[str, torch.Tensor]:
        x = self.patch_embed(x)
        B, _, h, w = x.shape
        x = x.flatten(2).transpose(1, 2)
        prefix = [self.cls_token.expand(B, -1, -1)]
        if self.n_storage_tokens > 0:
            prefix.append(self.storage_tokens.expand(B, -1, -1))
        x = torch.cat(prefix + [x], dim=1)
        rope = self.rope_embed(h, w)
        for blk in self.blocks:
            x = blk(x, rope)
        xn = self.norm(x)
        n0 = self.n_storage_tokens + 1
        return {
            "x_norm_clstoken": xn[:, 0],
            "x_storage_tokens": xn[:, 1:n0],
            "x_norm_patchtokens": xn[:, n0:],
            "x_prenorm": x,
            "h_patches": h,
            "w_patches": w,
        }

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Normalised patch tokens [B, h*w, D] of an already normalised image."""
        return self.forward_features(x)["x_norm_patchtokens"]


class DinoV3(nn.Module):
    """SPAR's DINOv3FeatureExtractor: ImageNet normalisation + backbone (``model``)."""

    def __init__(self, cfg: Optional[Dict[str, Any]] = None, seed: int = 0, perturb: bool = False,
                 device=None):
        super().__init__()
        c = resolve_config("dino", cfg)
        self.model = DinoV3Backbone(c, seed=seed, perturb=perturb, device=device)
        self.embed_dim = self.model.embed_dim
        self.patch_size = self.model.patch_size
        self.register_buffer("mean", torch.tensor(c["mean"], dtype=torch.float32, device=device).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(c["std"], dtype=torch.float32, device=device).view(1, 3, 1, 1))
        self.eval()

    def preprocess(self, images: torch.Tensor) -> torch.Tensor:
        x = (images - self.mean) / self.std
        H, W = x.shape[-2:]
        nh, nw = (H // self.patch_size) * self.patch_size, (W // self.patch_size) * self.patch_size
        if (nh, nw) != (H, W):
            x = F.interpolate(x, size=(nh, nw), mode="bilinear", align_corners=False)
        return x

    def forward_features(self, images: torch.Tensor) -> Dict[str, torch.Tensor]:
        return self.model.forward_features(self.preprocess(images))

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """images in [0, 1], [B, 3, H, W] -> patch tokens [B, (H/16)*(W/16), D]."""
        return self.forward_features(images)["x_norm_patchtokens"]
