#!/usr/bin/python3
"""LSeg image encoder reference (``clip_vitl16_384``), float32 or float64.

``LSegEncoder(cfg)`` holds the image path of lang-seg's ``LSegNet`` with its key layout, i.e.
the keys of LSeg's Lightning checkpoint after removing ``net.`` (``strip_net_prefix``)::

  pretrained.model.cls_token [1,1,W]  pretrained.model.pos_embed [1,1+24*24,W]
  pretrained.model.patch_embed.proj.{weight [W,3,16,16],bias}
  pretrained.model.blocks.i.{norm1,norm2}.{weight,bias}
  pretrained.model.blocks.i.attn.qkv.{weight [3W,W],bias}  .attn.proj.{weight,bias}
  pretrained.model.blocks.i.mlp.fc1.{weight,bias}  .mlp.fc2.{weight,bias}
  pretrained.model.norm.{weight,bias}  pretrained.model.head.{weight [1000,W],bias}  (unused)
  pretrained.act_postprocess{1..4}.0.project.0.{weight [W,2W],bias}     readout projection
  pretrained.act_postprocess1.3 Conv1x1 W->256, .4 ConvTranspose k4 s4
  pretrained.act_postprocess2.3 Conv1x1 W->512, .4 ConvTranspose k2 s2
  pretrained.act_postprocess3.3 Conv1x1 W->1024
  pretrained.act_postprocess4.3 Conv1x1 W->1024, .4 Conv3x3 stride 2 pad 1
  scratch.layer{1..4}_rn.weight   Conv3x3 -> features, no bias
  scratch.refinenet{1..4}.out_conv.{weight,bias}                            Conv1x1
  scratch.refinenet{1..4}.resConfUnit{1,2}.conv{1,2}.weight                 Conv3x3, no bias
  scratch.refinenet{1..4}.resConfUnit{1,2}.bn{1,2}.{weight,bias,running_mean,running_var,
                                                    num_batches_tracked}
  scratch.head1.{weight [512,256,1,1],bias}

The checkpoint also holds ``net.clip_pretrained.*``: a whole OpenAI CLIP ViT-B/32 (visual and
text) whose text part is what SPAR/LSeg use to encode prompts; ``split_lseg_state_dict`` gives
the image keys, the CLIP text keys (for ``CLIPTextEncoder``) and the rest.

Forward (SPAR's ``LSegFeatureExtractor.extract_features``, half_res=True):
  x = image as SPAR passes it: in [0,1], NOT normalised (cfg input_norm "none"; "lseg" applies
      LSeg's own training normalisation (x - 0.5) / 0.5 instead)
  timm ViT-L/16 (LayerNorm eps 1e-6, exact GELU, qkv bias): [cls, patches] + pos_embed whose
      24x24 grid is resized bilinearly (align_corners=False) to (H/16, W/16); the outputs of
      blocks 5, 11, 17, 23 (before the final norm) are the four hooks
  per hook: readout GELU(Linear(cat(patch, cls))) -> [B, W, H/16, W/16] -> reassemble
      (Conv1x1, then ConvT x4 / ConvT x2 / nothing / Conv3x3 s2): H/4, H/8, H/16, H/32
  layerN_rn Conv3x3; RefineNet fusion: out = x0 (+ RCU1(x1)); out = RCU2(out);
      bilinear x2 align_corners=True; out_conv.  RCU(x) = x + BN2(conv2(relu(BN1(conv1(relu(x))))))
      with BatchNorm in eval mode (running statistics); path4 = ref4(l4), path3 = ref3(path4, l3) ...
  head1 Conv1x1 features -> 512: [B, 512, H/2, W/2]
H must be a multiple of 32 (the stride-2 conv of the 4th hook).
"""
import math
from typing import Any, Dict, Optional, Tuple

import torch
import torch.nn as nn
import torch.nn.functional as F

from .backbones import add_prefix, attention, randomize_, resolve_config, strip_prefix

NET_PREFIX = "net."
CLIP_PREFIX = "clip_pretrained."


def strip_net_prefix(state_dict: Dict[str, Any]) -> Dict[str, Any]:
    """Keys under ``net.`` of LSeg's checkpoint state_dict, prefix removed (as SPAR does)."""
    return strip_prefix(state_dict, NET_PREFIX)


def add_net_prefix(state_dict: Dict[str, Any]) -> Dict[str, Any]:
    return add_prefix(state_dict, NET_PREFIX)


_CLIP_TEXT_ROOTS = ("token_embedding.", "positional_embedding", "transformer.", "ln_final.",
                    "text_projection")


def split_lseg_state_dict(state_dict: Dict[str, Any]) -> Tuple[Dict[str, Any], Dict[str, Any], Dict[str, Any]]:
    """(image-encoder keys for LSegEncoder, CLIP text keys for CLIPTextEncoder, the rest).

    Accepts keys with or without ``net.``.  The rest is the CLIP visual tower and
    ``clip_pretrained.logit_scale``, which no SPAR inference path uses."""
    sd = state_dict
    if any(k.startswith(NET_PREFIX) for k in sd):
        sd = strip_net_prefix(sd)
    image, text, rest = {}, {}, {}
    for k, v in sd.items():
        if k.startswith(CLIP_PREFIX):
            sub = k[len(CLIP_PREFIX):]
            if sub.startswith(_CLIP_TEXT_ROOTS):
                text[sub] = v
            else:
                rest[k] = v
        elif k.startswith("pretrained.") or k.startswith("scratch."):
            image[k] = v
        else:
            rest[k] = v
    return image, text, rest


# ---------------------------------------------------------------------------- timm ViT-L/16

class TimmAttention(nn.Module):
    def __init__(self, dim: int, heads: int, device=None):
        super().__init__()
        self.num_heads = heads
        self.qkv = nn.Linear(dim, 3 * dim, bias=True, device=device)
        self.proj = nn.Linear(dim, dim, device=device)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, N, C = x.shape
        qkv = self.qkv(x).reshape(B, N, 3, self.num_heads, C // self.num_heads).permute(2, 0, 3, 1, 4)
        o = attention(qkv[0], qkv[1], qkv[2])
        return self.proj(o.transpose(1, 2).reshape(B, N, C))


class TimmMlp(nn.Module):
    def __init__(self, dim: int, hidden: int, device=None):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden, device=device)
        self.act = nn.GELU()
        self.fc2 = nn.Linear(hidden, dim, device=device)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(self.act(self.fc1(x)))


class TimmBlock(nn.Module):
    def __init__(self, dim: int, heads: int, mlp_ratio: float, eps: float, device=None):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=eps, device=device)
        self.attn = TimmAttention(dim, heads, device=device)
        self.norm2 = nn.LayerNorm(dim, eps=eps, device=device)
        self.mlp = TimmMlp(dim, int(dim * mlp_ratio), device=device)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.norm1(x))
        return x + self.mlp(self.norm2(x))


class TimmPatchEmbed(nn.Module):
    def __init__(self, patch: int, dim: int, device=None):
        super().__init__()
        self.proj = nn.Conv2d(3, dim, kernel_size=patch, stride=patch, device=device)


class TimmViT(nn.Module):
    """timm 0.4.12 VisionTransformer (vit_large_patch16_384) as lang-seg's forward_flex runs it."""

    def __init__(self, c: Dict[str, Any], device=None):
        super().__init__()
        w = int(c["width"])
        self.patch_size = int(c["patch_size"])
        grid = int(c["pretrain_img_size"]) // self.patch_size
        self.cls_token = nn.Parameter(torch.zeros(1, 1, w, device=device))
        self.pos_embed = nn.Parameter(torch.zeros(1, 1 + grid * grid, w, device=device))
        self.patch_embed = TimmPatchEmbed(self.patch_size, w, device=device)
        eps = float(c["ln_eps"])
        self.blocks = nn.ModuleList([TimmBlock(w, int(c["num_heads"]), float(c["mlp_ratio"]), eps, device=device)
                                     for _ in range(int(c["depth"]))])
        self.norm = nn.LayerNorm(w, eps=eps, device=device)
        self.head = nn.Linear(w, int(c["num_classes"]), device=device)

    def resized_pos_embed(self, gh: int, gw: int) -> torch.Tensor:
        tok, grid = self.pos_embed[:, :1], self.pos_embed[0, 1:]
        g0 = int(math.sqrt(grid.shape[0]))
        grid = grid.reshape(1, g0, g0, -1).permute(0, 3, 1, 2)
        grid = F.interpolate(grid, size=(gh, gw), mode="bilinear", align_corners=False)
        grid = grid.permute(0, 2, 3, 1).reshape(1, gh * gw, -1)
        return torch.cat([tok, grid], dim=1)

    def forward_hooks(self, x: torch.Tensor, hooks) -> Tuple[list, int, int]:
        """Outputs of the blocks listed in ``hooks`` (block outputs, before ``norm``)."""
        B, _, H, W = x.shape
        gh, gw = H // self.patch_size, W // self.patch_size
        pos = self.resized_pos_embed(gh, gw)
        x = self.patch_embed.proj(x).flatten(2).transpose(1, 2)
        x = torch.cat([self.cls_token.expand(B, -1, -1), x], dim=1) + pos
        outs = {}
        last = max(hooks)
        for i, blk in enumerate(self.blocks):
            x = blk(x)
            if i in hooks:
                outs[i] = x
            if i == last:
                break  # the rest (and the final norm) do not reach the features
        return [outs[i] for i in hooks], gh, gw


class ProjectReadout(nn.Module):
    def __init__(self, dim: int, device=None):
        super().__init__()
        self.project = nn.Sequential(nn.Linear(2 * dim, dim, device=device), nn.GELU())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        readout = x[:, 0:1].expand_as(x[:, 1:])
        return self.project(torch.cat([x[:, 1:], readout], dim=-1))


class Transpose12(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x.transpose(1, 2)


class FixedUnflattenSlot(nn.Module):
    """Index 2 of act_postprocess: an Unflatten to the 384-pixel grid that the forward skips."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # pragma: no cover - never called
        raise RuntimeError("the grid comes from the input size")


class BackbonePretrained(nn.Module):
    """``pretrained``: the ViT (``model``) and the four ``act_postprocess`` reassemble stacks."""

    def __init__(self, c: Dict[str, Any], device=None):
        super().__init__()
        w = int(c["width"])
        f = [int(v) for v in c["reassemble"]]
        if c["readout"] != "project":
            raise NotImplementedError("only readout='project' (LSeg's default) is implemented")
        self.model = TimmViT(c, device=device)

        def stack(i, tail):
            return nn.Sequential(ProjectReadout(w, device=device), Transpose12(), FixedUnflattenSlot(),
                                 nn.Conv2d(w, f[i], kernel_size=1, device=device), *tail)

        self.act_postprocess1 = stack(0, [nn.ConvTranspose2d(f[0], f[0], kernel_size=4, stride=4, device=device)])
        self.act_postprocess2 = stack(1, [nn.ConvTranspose2d(f[1], f[1], kernel_size=2, stride=2, device=device)])
        self.act_postprocess3 = stack(2, [])
        self.act_postprocess4 = stack(3, [nn.Conv2d(f[3], f[3], kernel_size=3, stride=2, padding=1, device=device)])

    def reassemble(self, i: int, tokens: torch.Tensor, gh: int, gw: int) -> torch.Tensor:
        seq = [self.act_postprocess1, self.act_postprocess2, self.act_postprocess3, self.act_postprocess4][i]
        x = seq[1](seq[0](tokens))          # [B, W, gh*gw]
        x = x.unflatten(2, (gh, gw))        # forward_layers' Unflatten to the actual grid
        for m in list(seq)[3:]:
            x = m(x)
        return x


class ResidualConvUnit(nn.Module):
    """ResidualConvUnit_custom with bn=True, activation ReLU (not in place)."""

    def __init__(self, features: int, use_bn: bool, device=None):
        super().__init__()
        self.use_bn = use_bn
        self.conv1 = nn.Conv2d(features, features, 3, padding=1, bias=not use_bn, device=device)
        self.conv2 = nn.Conv2d(features, features, 3, padding=1, bias=not use_bn, device=device)
        if use_bn:
            self.bn1 = nn.BatchNorm2d(features, device=device)
            self.bn2 = nn.BatchNorm2d(features, device=device)

    @staticmethod
    def _bn(bn: nn.BatchNorm2d, x: torch.Tensor) -> torch.Tensor:
        # always eval-mode statistics, whatever .train() says
        return F.batch_norm(x, bn.running_mean, bn.running_var, bn.weight, bn.bias, False, 0.0, bn.eps)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.conv1(F.relu(x))
        if self.use_bn:
            out = self._bn(self.bn1, out)
        out = self.conv2(F.relu(out))
        if self.use_bn:
            out = self._bn(self.bn2, out)
        return out + x


class FeatureFusionBlock(nn.Module):
    """FeatureFusionBlock_custom(deconv=False, expand=False, align_corners=True)."""

    def __init__(self, features: int, use_bn: bool, device=None):
        super().__init__()
        self.out_conv = nn.Conv2d(features, features, kernel_size=1, device=device)
        self.resConfUnit1 = ResidualConvUnit(features, use_bn, device=device)
        self.resConfUnit2 = ResidualConvUnit(features, use_bn, device=device)

    def forward(self, x0: torch.Tensor, x1: Optional[torch.Tensor] = None) -> torch.Tensor:
        out = x0
        if x1 is not None:
            out = out + self.resConfUnit1(x1)
        out = self.resConfUnit2(out)
        out = F.interpolate(out, scale_factor=2, mode="bilinear", align_corners=True)
        return self.out_conv(out)


class Scratch(nn.Module):
    def __init__(self, c: Dict[str, Any], device=None):
        super().__init__()
        f = [int(v) for v in c["reassemble"]]
        n = int(c["features"])
        bn = bool(c["use_bn"])
        self.layer1_rn = nn.Conv2d(f[0], n, 3, padding=1, bias=False, device=device)
        self.layer2_rn = nn.Conv2d(f[1], n, 3, padding=1, bias=False, device=device)
        self.layer3_rn = nn.Conv2d(f[2], n, 3, padding=1, bias=False, device=device)
        self.layer4_rn = nn.Conv2d(f[3], n, 3, padding=1, bias=False, device=device)
        self.refinenet1 = FeatureFusionBlock(n, bn, device=device)
        self.refinenet2 = FeatureFusionBlock(n, bn, device=device)
        self.refinenet3 = FeatureFusionBlock(n, bn, device=device)
        self.refinenet4 = FeatureFusionBlock(n, bn, device=device)
        self.head1 = nn.Conv2d(n, int(c["feature_dim"]), kernel_size=1, device=device)


class LSegEncoder(nn.Module):
    """LSeg image features at H/2 as SPAR extracts them (``extract_features``, half_res)."""

    def __init__(self, cfg: Optional[Dict[str, Any]] = None, seed: int = 0, perturb: bool = False,
                 device=None):
        super().__init__()
        c = resolve_config("lseg", cfg)
        self.cfg = c
        if len(c["hooks"]) != 4 or len(c["reassemble"]) != 4:
            raise ValueError("LSeg needs four hooks and four reassemble widths")
        self.hooks = [int(h) for h in c["hooks"]]
        self.input_norm = str(c["input_norm"])
        self.out_c = int(c["feature_dim"])
        self.pretrained = BackbonePretrained(c, device=device)
        self.scratch = Scratch(c, device=device)
        if str(device) != "meta":
            randomize_(self, seed, perturb)
        self.eval()

    def normalize_input(self, images: torch.Tensor) -> torch.Tensor:
        if self.input_norm == "none":
            return images
        if self.input_norm == "lseg":
            return (images - 0.5) / 0.5
        raise ValueError(f"unknown input_norm {self.input_norm!r}")

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """images in [0, 1], [B, 3, H, W] -> features [B, feature_dim, H/2, W/2]."""
        x = self.normalize_input(images)
        tokens, gh, gw = self.pretrained.model.forward_hooks(x, self.hooks)
        layers = [self.pretrained.reassemble(i, t, gh, gw) for i, t in enumerate(tokens)]
        s = self.scratch
        l1, l2, l3, l4 = s.layer1_rn(layers[0]), s.layer2_rn(layers[1]), s.layer3_rn(layers[2]), s.layer4_rn(layers[3])
        p4 = s.refinenet4(l4)
        p3 = s.refinenet3(p4, l3)
        p2 = s.refinenet2(p3, l2)
        p1 = s.refinenet1(p2, l1)
        return s.head1(p1)
