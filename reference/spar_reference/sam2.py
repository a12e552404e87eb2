#!/usr/bin/python3
"""SAM2.1's mask refinement as SPAR runs it (``SPAR._sam2_refine_masks``), float32 or float64.

The single-image path with a mask prompt, written from the official code (facebookresearch/sam2:
``SAM2ImagePredictor.set_image`` / ``predict``, ``backbones/hieradet.py``,
``backbones/image_encoder.py``, ``sam/prompt_encoder.py``, ``sam/mask_decoder.py``,
``sam/transformer.py``) as functions of the checkpoint's tensors (official key layout, the
``model`` dict of sam2.1_hiera_*.pt). The sizes come from ``spar_convert.sam2_config`` (the
converter's own description of a variant). Per view:

  image [3, H, W] in [0, 1] -> uint8 by truncation (x 255) -> bilinear to 1024x1024
      (align_corners=False) -> ImageNet normalisation
  Hiera: Conv 7x7 s4 -> + pos (bicubic of the background embedding + tiled window embedding)
      -> blocks (LN 1e-6; windowed attention over zero-padded windows, the pad tokens stay keys
      and values; q max-pooled 2x2 at the first block of stages 2-4, whose shortcut is the
      max-pooled projection of the normed input; MLP with exact GELU) -> the 4 stage outputs
  FPN neck (1x1 convs, deepest first; top-down nearest x2 into level 2 only; scalp 1) ->
      L0, L1, L2; image_embed = L2 + no_mem_embed; feat_s0 = conv_s0(L0), feat_s1 = conv_s1(L1)
  prompt: binary = P(dynamic) > 0.5; logits = 20 binary - 10, bilinear to 256x256; dense =
      mask_downscaling (Conv k2s2, LN2d, GELU, Conv k2s2, LN2d, GELU, Conv 1x1)
  decoder: tokens [obj_score, iou, 4 mask tokens]; two-way transformer (2 layers, LN 1e-5)
      over image_embed + dense with the random-Fourier dense PE; upscaling ConvT/LN2d/GELU +
      feat_s1, ConvT/GELU + feat_s0; hypernetworks 1-3 . upscaled -> 3 low-res logit maps; IoU =
      sigmoid(MLP(iou token))[1:4]
  output: logits bilinear to H x W (align_corners=False), > 0; the mask of the highest IoU
      (the first on a tie); a view with fewer than 10 dynamic pixels, or more than H*W - 10,
      is not refined: its output is the binary prompt.

Not on the path (and not computed): the sine position encodings, the object-score head,
hypernetwork 0, SAM2's memory and object-pointer modules.
"""

from __future__ import annotations

import math
import os
from typing import Any, Dict, List, Optional

import torch
import torch.nn.functional as F

from spar_convert.sam2_config import (IMAGE_SIZE, MASK_INPUT_SIZE, DECODER_HEADS, NUM_MASK_TOKENS,
                                      Sam2Config, discarded_tensors, is_unused, used_tensors)

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
SKIP_MIN = 10               # SPAR refines a view only when 10 <= dynamic pixels <= H*W - 10
PROMPT_SCALE, PROMPT_BIAS = 20.0, -10.0


def attention(q, k, v):
    """softmax(q k^T / sqrt(hd)) v over the last two dims (torch 1.13 has no SDPA)."""
    s = (q @ k.transpose(-1, -2)) / math.sqrt(q.shape[-1])
    return torch.softmax(s, dim=-1) @ v


def layer_norm(x, sd, p, eps):
    return F.layer_norm(x, x.shape[-1:], sd[p + "weight"], sd[p + "bias"], eps)


def layer_norm_2d(x, sd, p, eps=1e-6):
    """LayerNorm2d over the channels of [B, C, H, W] (sam2_utils.LayerNorm2d)."""
    u = x.mean(1, keepdim=True)
    s = (x - u).pow(2).mean(1, keepdim=True)
    x = (x - u) / torch.sqrt(s + eps)
    return sd[p + "weight"][:, None, None] * x + sd[p + "bias"][:, None, None]


def linear(x, sd, p):
    return F.linear(x, sd[p + "weight"], sd[p + "bias"])


def mlp(x, sd, p, layers, act=F.relu):
    for i in range(layers):
        x = linear(x, sd, "%s%d." % (p, i))
        if i < layers - 1:
            x = act(x)
    return x


def gelu(x):
    return F.gelu(x)  # exact (erf) form, as every nn.GELU() on this path


# ------------------------------------------------------------------------------- image encoder
def preprocess(image01: torch.Tensor, dtype, size: int = IMAGE_SIZE) -> torch.Tensor:
    """[3, H, W] float in [0, 1] -> [1, 3, size, size] (the variant's image_size, 1024 in the
    official ones): SPAR's uint8 cast (x 255 in float32, truncated), ToTensor (/ 255), bilinear
    Resize, Normalize."""
    u8 = (image01.to(torch.float32) * 255.0).to(torch.uint8)
    x = u8.to(dtype)[None] / 255.0
    x = F.interpolate(x, size=(size, size), mode="bilinear", align_corners=False)
    mean = torch.tensor(IMAGENET_MEAN, dtype=dtype)[None, :, None, None]
    std = torch.tensor(IMAGENET_STD, dtype=dtype)[None, :, None, None]
    return (x - mean) / std


def position_embedding(sd, cfg: Sam2Config, side: int) -> torch.Tensor:
    """Hiera._get_pos_embed: [1, side, side, C0] (input-independent)."""
    tr = "image_encoder.trunk."
    pos = F.interpolate(sd[tr + "pos_embed"], size=(side, side), mode="bicubic", align_corners=False)
    win = sd[tr + "pos_embed_window"]
    pos = pos + win.tile([1, 1, side // win.shape[2], side // win.shape[3]])
    return pos.permute(0, 2, 3, 1)


def window_partition(x, w):
    """[1, H, W, C] -> [nW, w, w, C] (zero-padded to multiples of w, windows row-major)."""
    b, h, wd, c = x.shape
    ph, pw = (w - h % w) % w, (w - wd % w) % w
    x = F.pad(x, (0, 0, 0, pw, 0, ph))
    hp, wp = h + ph, wd + pw
    x = x.view(b, hp // w, w, wp // w, w, c).permute(0, 1, 3, 2, 4, 5)
    return x.reshape(-1, w, w, c), (hp, wp)


def window_unpartition(x, w, pad_hw, hw):
    hp, wp = pad_hw
    b = x.shape[0] // (hp * wp // w // w)
    x = x.view(b, hp // w, wp // w, w, w, -1).permute(0, 1, 3, 2, 4, 5).reshape(b, hp, wp, -1)
    return x[:, :hw[0], :hw[1], :]


def max_pool_2x2(x):
    """[B, H, W, C] -> [B, H/2, W/2, C] (MaxPool2d(2, 2) over the spatial dims)."""
    return F.max_pool2d(x.permute(0, 3, 1, 2), 2, 2).permute(0, 2, 3, 1)


def hiera_block(x, sd, p, blk):
    """MultiScaleBlock.forward, x [1, H, W, dim]."""
    dim, dim_out, heads, window = blk["dim"], blk["dim_out"], blk["heads"], blk["window"]
    shortcut = x
    x = layer_norm(x, sd, p + "norm1.", 1e-6)
    if dim != dim_out:
        shortcut = linear(x, sd, p + "proj.")
        if blk["q_pool"]:
            shortcut = max_pool_2x2(shortcut)
    h, w = x.shape[1:3]
    pad_hw = None
    if window > 0:
        x, pad_hw = window_partition(x, window)
    # MultiScaleAttention
    b, wh, ww, _ = x.shape
    qkv = linear(x, sd, p + "attn.qkv.").reshape(b, wh * ww, 3, heads, -1)
    q, k, v = qkv.unbind(2)
    if blk["q_pool"]:
        q = max_pool_2x2(q.reshape(b, wh, ww, -1))
        wh, ww = q.shape[1:3]
        q = q.reshape(b, wh * ww, heads, -1)
    a = attention(q.transpose(1, 2), k.transpose(1, 2), v.transpose(1, 2)).transpose(1, 2)
    x = linear(a.reshape(b, wh, ww, -1), sd, p + "attn.proj.")
    if blk["q_pool"]:
        window //= 2
        h, w = shortcut.shape[1:3]
        pad_hw = (h + (window - h % window) % window, w + (window - w % window) % window) if window else None
    if window > 0:
        x = window_unpartition(x, window, pad_hw, (h, w))
    x = shortcut + x
    return x + mlp(layer_norm(x, sd, p + "norm2.", 1e-6), sd, p + "mlp.layers.", 2, gelu)


def image_encoder(x, sd, cfg: Sam2Config, record=None) -> Dict[str, torch.Tensor]:
    """[1, 3, 1024, 1024] -> image_embed [1, D, 64, 64] and the high-resolution features."""
    tr = "image_encoder.trunk."
    x = F.conv2d(x, sd[tr + "patch_embed.proj.weight"], sd[tr + "patch_embed.proj.bias"], stride=4, padding=3)
    x = x.permute(0, 2, 3, 1)
    x = x + position_embedding(sd, cfg, x.shape[1])
    ends, stages = cfg.stage_ends(), []
    for i, blk in enumerate(cfg.blocks()):
        x = hiera_block(x, sd, tr + "blocks.%d." % i, blk)
        if i in ends:
            stages.append(x.permute(0, 3, 1, 2))
    if record is not None:
        for i, s in enumerate(stages):
            record["sam2_trunk_%d" % i] = s
    # FpnNeck: convs[0] takes the deepest stage; top-down (nearest x2) into levels 2 and 3 only
    n = len(stages) - 1
    levels: List[Optional[torch.Tensor]] = [None] * len(stages)
    prev = None
    for i in range(n, -1, -1):
        lat = F.conv2d(stages[i], sd["image_encoder.neck.convs.%d.conv.weight" % (n - i)],
                       sd["image_encoder.neck.convs.%d.conv.bias" % (n - i)])
        if i in (2, 3) and prev is not None:
            # the official code upsamples in float32 (.to(float32)); float64 keeps float64
            prev = lat + F.interpolate(prev, scale_factor=2.0, mode="nearest")
        else:
            prev = lat
        levels[i] = prev
    md = "sam_mask_decoder."
    out = {
        "image_embed": levels[2] + sd["no_mem_embed"].reshape(1, -1, 1, 1),
        "feat_s0": F.conv2d(levels[0], sd[md + "conv_s0.weight"], sd[md + "conv_s0.bias"]),
        "feat_s1": F.conv2d(levels[1], sd[md + "conv_s1.weight"], sd[md + "conv_s1.bias"]),
    }
    if record is not None:
        record.update({"sam2_" + k: v for k, v in out.items()})
    return out


# ------------------------------------------------------------------------- prompt and decoder
def dense_pe(sd, side: int, dtype) -> torch.Tensor:
    """PositionEmbeddingRandom over the side x side grid: [1, D, side, side]."""
    g = sd["sam_prompt_encoder.pe_layer.positional_encoding_gaussian_matrix"]
    c = (torch.arange(side, dtype=dtype) + 0.5) / side
    yy, xx = torch.meshgrid(c, c, indexing="ij")
    coords = torch.stack([xx, yy], dim=-1) * 2 - 1
    p = 2 * math.pi * (coords @ g)
    return torch.cat([torch.sin(p), torch.cos(p)], dim=-1).permute(2, 0, 1)[None]


def mask_prompt(prob: torch.Tensor, dtype, size: int = MASK_INPUT_SIZE) -> torch.Tensor:
    """P(dynamic) [H, W] -> the mask logits prompt [1, 1, size, size] (+-10, resized; the
    variant's mask_input_size(), 256 in the official ones)."""
    binary = (prob > 0.5).to(dtype)
    logits = binary * PROMPT_SCALE + PROMPT_BIAS
    return F.interpolate(logits[None, None], size=(size, size), mode="bilinear",
                         align_corners=False)


def prompt_dense(sd, logits):
    p = "sam_prompt_encoder.mask_downscaling."
    x = F.conv2d(logits, sd[p + "0.weight"], sd[p + "0.bias"], stride=2)
    x = gelu(layer_norm_2d(x, sd, p + "1."))
    x = F.conv2d(x, sd[p + "3.weight"], sd[p + "3.bias"], stride=2)
    x = gelu(layer_norm_2d(x, sd, p + "4."))
    return F.conv2d(x, sd[p + "6.weight"], sd[p + "6.bias"])


def decoder_attention(sd, p, q, k, v):
    q, k, v = linear(q, sd, p + "q_proj."), linear(k, sd, p + "k_proj."), linear(v, sd, p + "v_proj.")

    def heads(x):
        return x.reshape(x.shape[0], x.shape[1], DECODER_HEADS, -1).transpose(1, 2)
    a = attention(heads(q), heads(k), heads(v)).transpose(1, 2)
    return linear(a.reshape(a.shape[0], a.shape[1], -1), sd, p + "out_proj.")


def two_way_transformer(sd, src, pe, tokens):
    """TwoWayTransformer: image [1, D, h, w] + PE, tokens [1, T, D] -> (queries, keys)."""
    t = "sam_mask_decoder.transformer."
    keys = src.flatten(2).permute(0, 2, 1)
    key_pe = pe.flatten(2).permute(0, 2, 1)
    queries = tokens
    for layer in range(2):
        p = t + "layers.%d." % layer
        if layer == 0:  # skip_first_layer_pe: no PE, no residual
            queries = decoder_attention(sd, p + "self_attn.", queries, queries, queries)
        else:
            q = queries + tokens
            queries = queries + decoder_attention(sd, p + "self_attn.", q, q, queries)
        queries = layer_norm(queries, sd, p + "norm1.", 1e-5)
        q, k = queries + tokens, keys + key_pe
        queries = layer_norm(queries + decoder_attention(sd, p + "cross_attn_token_to_image.", q, k, keys),
                             sd, p + "norm2.", 1e-5)
        queries = layer_norm(queries + mlp(queries, sd, p + "mlp.layers.", 2), sd, p + "norm3.", 1e-5)
        q, k = queries + tokens, keys + key_pe
        keys = layer_norm(keys + decoder_attention(sd, p + "cross_attn_image_to_token.", k, q, queries),
                          sd, p + "norm4.", 1e-5)
    q, k = queries + tokens, keys + key_pe
    queries = queries + decoder_attention(sd, t + "final_attn_token_to_image.", q, k, keys)
    return layer_norm(queries, sd, t + "norm_final_attn.", 1e-5), keys


def conv_transpose_2x2(x, sd, p):
    return F.conv_transpose2d(x, sd[p + "weight"], sd[p + "bias"], stride=2)


def mask_decoder(sd, feats, dense, pe, record=None):
    """MaskDecoder.predict_masks with multimask_output: low-res logits [3, 256, 256], IoU [3]."""
    md = "sam_mask_decoder."
    tokens = torch.cat([sd[md + "obj_score_token.weight"], sd[md + "iou_token.weight"],
                        sd[md + "mask_tokens.weight"]], dim=0)[None]
    src = feats["image_embed"] + dense
    hs, keys = two_way_transformer(sd, src, pe, tokens)
    b, c, h, w = src.shape
    src = keys.transpose(1, 2).reshape(b, c, h, w)
    up = gelu(layer_norm_2d(conv_transpose_2x2(src, sd, md + "output_upscaling.0.") + feats["feat_s1"], sd,
                            md + "output_upscaling.1."))
    up = gelu(conv_transpose_2x2(up, sd, md + "output_upscaling.3.") + feats["feat_s0"])
    # multimask output: mask tokens 1..3 (token 0's hypernetwork is never read)
    hyper = torch.stack([mlp(hs[:, 2 + m], sd, md + "output_hypernetworks_mlps.%d.layers." % m, 3)
                         for m in range(1, NUM_MASK_TOKENS)], dim=1)
    bu, cu, hu, wu = up.shape
    logits = (hyper @ up.reshape(bu, cu, hu * wu)).reshape(bu, -1, hu, wu)
    iou = torch.sigmoid(mlp(hs[:, 1], sd, md + "iou_prediction_head.layers.", 3))[:, 1:]
    if record is not None:
        record.update(sam2_tokens_out=hs, sam2_upscaled=up)
    return logits[0], iou[0]


# ----------------------------------------------------------------------------------- refine
def as_dtype(sd: Dict[str, torch.Tensor], cfg: Sam2Config, dtype) -> Dict[str, torch.Tensor]:
    """The path's tensors of a checkpoint's state dict, checked and in `dtype`."""
    out = {}
    for k, shape in used_tensors(cfg).items():
        if k not in sd:
            raise KeyError("SAM2 checkpoint has no %r" % k)
        if tuple(sd[k].shape) != shape:
            raise ValueError("SAM2 tensor %r has shape %s, expected %s" % (k, list(sd[k].shape), list(shape)))
        out[k] = sd[k].to(dtype)
    return out


def refine_view(sd, cfg: Sam2Config, image01: torch.Tensor, prob: torch.Tensor, dtype,
                record: Optional[Dict[str, Any]] = None) -> Dict[str, Any]:
    """One view: image [3, H, W] in [0, 1], P(dynamic) [H, W] -> {refined [H, W] 0/1, skipped,
    iou [3], chosen, logits [256, 256] of the chosen mask}."""
    h, w = prob.shape
    binary = (prob > 0.5).to(dtype)
    count = int(binary.sum().item())
    if count < SKIP_MIN or count > h * w - SKIP_MIN:
        return {"refined": binary, "skipped": True, "iou": None, "chosen": None, "logits": None,
                "dynamic_pixels": count}
    prompt = mask_prompt(prob, dtype, cfg.mask_input_size())
    feats = image_encoder(preprocess(image01, dtype, cfg.image_size), sd, cfg, record)
    dense = prompt_dense(sd, prompt)
    pe = dense_pe(sd, feats["image_embed"].shape[-1], dtype)
    logits, iou = mask_decoder(sd, feats, dense, pe, record)
    full = F.interpolate(logits[None], size=(h, w), mode="bilinear", align_corners=False)[0]
    chosen = int(torch.argmax(iou).item())  # torch's argmax: the first of equal maxima, as numpy's
    if record is not None:
        record.update(sam2_prompt=prompt, sam2_dense=dense, sam2_low_res_logits=logits)
    return {"refined": (full[chosen] > 0.0).to(dtype), "skipped": False, "iou": iou, "chosen": chosen,
            "logits": logits[chosen], "dynamic_pixels": count}


def refine_masks(sd, cfg: Sam2Config, images01: torch.Tensor, prob: torch.Tensor, dtype=torch.float64):
    """[V, 3, H, W] images and [V, H, W] P(dynamic) -> one refine_view result per view."""
    sd = as_dtype(sd, cfg, dtype)
    with torch.no_grad():
        return [refine_view(sd, cfg, images01[v], prob[v], dtype) for v in range(images01.shape[0])]


# ------------------------------------------------------------------------- test checkpoints
# The official model definition's key lists (hiera_l and hiera_t, made by building the model):
# the video path's tensors of an official file come from them (the same in every variant).
OFFICIAL_KEYS = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data", "sam2")


def official_keys(name: str) -> Dict[str, tuple]:
    """key -> shape of the official sam2.1 model `name` (hiera_l or hiera_t)."""
    out = {}
    with open(os.path.join(OFFICIAL_KEYS, "keys_%s.tsv" % name)) as f:
        for line in f:
            key, shape = line.rstrip("\n").split("\t")[:2]
            out[key] = tuple(int(x) for x in shape.strip("()").split(",") if x.strip())
    return out


def video_path_shapes() -> Dict[str, tuple]:
    """The tensors of an official file that no refinement reads (memory, object pointers, point
    prompts): width 256 in every official variant."""
    return {k: s for k, s in official_keys("hiera_t").items() if is_unused(k)}


def make_checkpoint(cfg: Sam2Config, seed: int = 0, unused_shapes=None) -> Dict[str, Any]:
    """{"model": state_dict} in the official key layout with random weights of sensible scale
    (Linear/Conv ~ U(+-1/sqrt(fan_in)), norms 1 + noise, biases and embeddings small), the
    discarded heads included, and `unused_shapes` (key -> shape: the video path's tensors of an
    official file) filled with noise so the file has every official key."""
    g = torch.Generator().manual_seed(seed)
    shapes = dict(used_tensors(cfg))
    shapes.update(discarded_tensors(cfg))
    shapes.update(unused_shapes or {})
    sd = {}
    for k, shape in shapes.items():
        if k.endswith("positional_encoding_gaussian_matrix"):
            t = torch.randn(shape, generator=g)            # scale 1, as the official buffer
        elif k.endswith("pos_embed") or k.endswith("pos_embed_window") or k.endswith("_token.weight") \
                or k.endswith("tokens.weight") or k == "no_mem_embed":
            t = 0.2 * torch.randn(shape, generator=g)
        elif len(shape) == 1 and (".norm" in k or "output_upscaling.1." in k or
                                  "mask_downscaling.1." in k or "mask_downscaling.4." in k) and k.endswith("weight"):
            t = 1.0 + 0.1 * torch.randn(shape, generator=g)
        elif len(shape) == 1:
            t = 0.05 * torch.randn(shape, generator=g)
        else:
            fan_in = shape[1] * (shape[2] * shape[3] if len(shape) == 4 else 1)
            if "output_upscaling" in k:                       # ConvTranspose: [in, out, k, k]
                fan_in = shape[0]
            bound = 1.0 / math.sqrt(fan_in)
            t = (torch.rand(shape, generator=g) * 2 - 1) * bound
        sd[k] = t.to(torch.float32).contiguous()
    return {"model": sd}
