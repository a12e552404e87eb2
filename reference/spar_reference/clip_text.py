#!/usr/bin/python3
"""CLIP text transformer reference (openai/CLIP ``clip/model.py``, ViT-B/32 text tower).

Key layout of OpenAI's state_dict (text part; the same keys appear under
``net.clip_pretrained.`` in LSeg's checkpoint, see ``lseg.split_lseg_state_dict``)::

    token_embedding.weight [49408, W]     positional_embedding [77, W]
    transformer.resblocks.i.ln_1.{weight,bias}
    transformer.resblocks.i.attn.in_proj_weight [3W, W]  .attn.in_proj_bias [3W]
    transformer.resblocks.i.attn.out_proj.{weight [W, W], bias}
    transformer.resblocks.i.ln_2.{weight,bias}
    transformer.resblocks.i.mlp.c_fc.{weight [4W, W], bias}  .mlp.c_proj.{weight [W, 4W], bias}
    ln_final.{weight,bias}               text_projection [W, E]   (x @ text_projection)

Forward: x = token_embedding[ids] + positional_embedding; per block (pre-norm, LayerNorm eps
1e-5): x += out_proj(MHA(ln_1(x)) with in_proj rows q|k|v, heads of W/heads, additive causal
mask (-inf above the diagonal)); x += c_proj(QuickGELU(c_fc(ln_2(x)))), QuickGELU(x) =
x * sigmoid(1.702 x); x = ln_final(x); out = x[b, argmax(ids[b])] @ text_projection (the end
token has the largest id).  Differences from the official code, nil in float32: CLIP's
LayerNorm subclass computes in float32 whatever the input dtype (here: the input's dtype, so
``.double()`` gives a float64 reference); the full CLIP model keeps weights in fp16 on CUDA.
"""
from typing import Any, Dict, Optional

import torch
import torch.nn as nn
import torch.nn.functional as F

from .backbones import attention, randomize_, resolve_config


class QuickGELU(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * torch.sigmoid(1.702 * x)


class CLIPMultiheadAttention(nn.Module):
    """nn.MultiheadAttention's parameter layout (in_proj_weight/bias, out_proj)."""

    def __init__(self, width: int, heads: int, device=None):
        super().__init__()
        self.heads = heads
        self.in_proj_weight = nn.Parameter(torch.zeros(3 * width, width, device=device))
        self.in_proj_bias = nn.Parameter(torch.zeros(3 * width, device=device))
        self.out_proj = nn.Linear(width, width, device=device)

    def _randomize_own_(self, g: torch.Generator, perturb: bool) -> None:
        w = self.in_proj_weight
        with torch.no_grad():
            w.copy_((torch.randn(w.shape, generator=g) / w.shape[1] ** 0.5).to(w.dtype))
            b = torch.randn(self.in_proj_bias.shape, generator=g) * (0.2 if perturb else 0.0)
            self.in_proj_bias.copy_(b.to(self.in_proj_bias.dtype))

    def forward(self, x: torch.Tensor, mask: Optional[torch.Tensor]) -> torch.Tensor:
        B, N, C = x.shape
        qkv = F.linear(x, self.in_proj_weight, self.in_proj_bias)
        qkv = qkv.reshape(B, N, 3, self.heads, C // self.heads).permute(2, 0, 3, 1, 4)
        o = attention(qkv[0], qkv[1], qkv[2], mask)
        return self.out_proj(o.transpose(1, 2).reshape(B, N, C))


class CLIPMlp(nn.Module):
    def __init__(self, width: int, device=None):
        super().__init__()
        self.c_fc = nn.Linear(width, 4 * width, device=device)
        self.gelu = QuickGELU()
        self.c_proj = nn.Linear(4 * width, width, device=device)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.c_proj(self.gelu(self.c_fc(x)))


class ResidualAttentionBlock(nn.Module):
    def __init__(self, width: int, heads: int, eps: float, device=None):
        super().__init__()
        self.attn = CLIPMultiheadAttention(width, heads, device=device)
        self.ln_1 = nn.LayerNorm(width, eps=eps, device=device)
        self.mlp = CLIPMlp(width, device=device)
        self.ln_2 = nn.LayerNorm(width, eps=eps, device=device)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.ln_1(x), mask)
        return x + self.mlp(self.ln_2(x))


class CLIPTransformer(nn.Module):
    def __init__(self, width: int, layers: int, heads: int, eps: float, device=None):
        super().__init__()
        self.resblocks = nn.ModuleList([ResidualAttentionBlock(width, heads, eps, device=device)
                                        for _ in range(layers)])

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        for blk in self.resblocks:
            x = blk(x, mask)
        return x


class CLIPTextEncoder(nn.Module):
    """Token ids [B, context] -> text embeddings [B, embed_dim] (not normalised)."""

    _matrix_params = ("text_projection",)

    def __init__(self, cfg: Optional[Dict[str, Any]] = None, seed: int = 0, perturb: bool = False,
                 device=None):
        super().__init__()
        c = resolve_config("clip", cfg)
        self.cfg = c
        w, n = int(c["width"]), int(c["context_length"])
        self.context_length = n
        self.token_embedding = nn.Embedding(int(c["vocab_size"]), w, device=device)
        self.positional_embedding = nn.Parameter(torch.zeros(n, w, device=device))
        self.transformer = CLIPTransformer(w, int(c["layers"]), int(c["heads"]), float(c["ln_eps"]), device=device)
        self.ln_final = nn.LayerNorm(w, eps=float(c["ln_eps"]), device=device)
        self.text_projection = nn.Parameter(torch.zeros(w, int(c["embed_dim"]), device=device))
        if str(device) != "meta":
            randomize_(self, seed, perturb)
        self.eval()

    def causal_mask(self, n: int, dtype: torch.dtype, device) -> torch.Tensor:
        return torch.full((n, n), float("-inf"), dtype=dtype, device=device).triu_(1)

    def forward(self, ids: torch.Tensor) -> torch.Tensor:
        ids = ids.long()
        x = self.token_embedding(ids) + self.positional_embedding
        x = self.transformer(x, self.causal_mask(ids.shape[1], x.dtype, x.device))
        x = self.ln_final(x)
        x = x[torch.arange(x.shape[0], device=x.device), ids.argmax(dim=-1)]
        return x @ self.text_projection


LSEG_LOGIT_SCALE = 1.0 / 0.07  # LSeg: exp(log(1 / 0.07)), a fixed tensor (not in the checkpoint)


def label_logits(image_features: torch.Tensor, text_embeddings: torch.Tensor,
                 logit_scale: float = LSEG_LOGIT_SCALE) -> torch.Tensor:
    """Open-vocabulary logits as LSeg / SPAR compute them: both sides L2-normalised over the
    channels, logits = scale * <image, text>.  image_features [B, C, H, W], text_embeddings
    [K, C] -> [B, K, H, W].  (The official code multiplies fp16 image features by the text
    features; here everything stays in the inputs' dtype.)"""
    img = image_features / image_features.norm(dim=1, keepdim=True)
    txt = text_embeddings / text_embeddings.norm(dim=-1, keepdim=True)
    return logit_scale * torch.einsum("bchw,kc->bkhw", img, txt.to(img.dtype))


def full_resolution_labels(logits: torch.Tensor) -> torch.Tensor:
    """The official label map of logits [B, K, H/2, W/2] (SPAR generate_semantic_predictions):
    LSeg's ``scratch.output_conv`` (an Interpolate of x2, bilinear, align_corners=True) on the
    logits, then the argmax over the prompts at H x W -> [B, H, W] (the first maximum). Not the
    half-resolution argmax enlarged: that differs wherever the labels change within two pixels."""
    import torch.nn.functional as F
    up = F.interpolate(logits, scale_factor=2, mode="bilinear", align_corners=True)
    return up.argmax(dim=1)
