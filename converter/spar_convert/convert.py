#!/usr/bin/python3
"""spar-convert: a SPAR checkpoint (+ DINOv3, LSeg, CLIP, BPE files) -> one packed safetensors file.

Standard library + numpy only: torch is never imported (checkpoints are read by the restricted
reader ``torch_checkpoint``). The output format is documented in ``converter/FORMAT.md``.

    spar-convert X.pt -o M.spar [--config PATH] [--fp16] [--dino DINO.pth] [--lseg LSEG.ckpt]
                 [--clip CLIP.pt] [--bpe MERGES.txt.gz] [--model-card CARD.json]
    spar-convert M.spar --model-card CARD.json -o M2.spar    (a packed model: its card replaced)

Steps: read every input lazily; take the configuration from ``--config`` or infer it from the
tensor shapes; list every tensor the engine needs for that configuration (``_plan``), checking
presence, shape and dtype of each before anything is written; fold BatchNorm and DINOv3's k-bias
mask; write the file (temporary file, then rename), tensor by tensor.
"""

from __future__ import annotations

import argparse
import gzip
import json
import math
import os
import re
import sys
import zlib

import numpy as np

from .model_config import (PRESETS, SparConfig, backbone_config, matching_preset, read_config_file,
                           resolve_config, stated_image_size)
from .model_card import ModelCardError, card_text, read_card
from . import quantize as quant
from . import sam2_plan
from .safetensors_file import SafetensorsError, SafetensorsFile, TensorSpec, write_safetensors
from .torch_checkpoint import CheckpointError, open_checkpoint, open_torchscript

PROG = "spar-convert"
FORMAT = "spar-vulkan"
FORMAT_VERSION = "1"      # a file without quantized matrices (readable by every engine so far)
QUANT_FORMAT_VERSION = "2"  # one with them (FORMAT.md, "Quantized matrices")
FORMAT_VERSIONS = (FORMAT_VERSION, QUANT_FORMAT_VERSION)
BN_EPS = 1e-5             # nn.BatchNorm2d's default eps (not stored in checkpoints)
FP16_MAX = 65504.0
FLOAT_DTYPES = ("float32", "float16", "bfloat16", "float64")
# sizes/options an inferred configuration cannot read from tensors: runtime or official defaults
RUNTIME_FIELDS = ("image_height", "image_width", "num_views", "num_input_views")

PREFIX = {"spar": "", "dino": "dino.", "lseg": "lseg.", "clip": "clip.", "sam2": sam2_plan.PACKED_PREFIX}
BPE_NAME = "clip.bpe_merges"
# The repository's copy of CLIP's merges table (MIT licence beside it), packed by default
# whenever the model has a CLIP text encoder, so its labels work without extra files.
DEFAULT_BPE = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..",
                                            "text", "data", "clip", "bpe_simple_vocab_16e6.txt.gz"))


class ConvertError(Exception):
    """A refusal: one line, naming the tensor or file."""


# ============================================================================ inputs
class Source:
    """Tensors of one component (spar, dino, lseg, clip) as TensorRefs, keys relative to the
    component (official key layout), plus how each key is spelled in its file."""

    def __init__(self, component):
        self.component = component
        self.tensors = {}      # key -> TensorRef
        self.origin = {}       # key -> "file: key as stored"
        self.used = set()
        self.where = None      # (file, prefix of the keys in that file), for error messages

    def add(self, key, ref, path, stored):
        self.tensors[key] = ref
        self.origin[key] = "%s: %s" % (os.path.basename(path), stored)

    def __contains__(self, key):
        return key in self.tensors

    def __bool__(self):
        return bool(self.tensors)

    def stored(self, key):
        return self.origin.get(key, key).split(": ", 1)[-1]

    def get(self, key, shape=None):
        """The TensorRef of key, checked: present, floating point, and of `shape` if given."""
        ref = self.tensors.get(key)
        if ref is None:
            file, pre = self.where or ("", PREFIX[self.component])
            raise ConvertError("missing tensor %r%s%s" % (
                pre + key, " in %s" % file if file else " (no %s weights given)" % self.component,
                ", expected shape %s" % list(shape) if shape is not None else ""))
        if ref.dtype not in FLOAT_DTYPES:
            raise ConvertError("tensor %r (%s) has dtype %s, which the converter cannot handle "
                               "(expected a floating-point tensor)"
                               % (self.stored(key), self.origin[key].split(":")[0], ref.dtype))
        if shape is not None and tuple(ref.shape) != tuple(shape):
            raise ConvertError("tensor %r (%s) has shape %s, expected %s from the configuration"
                               % (self.stored(key), self.origin[key].split(":")[0],
                                  list(ref.shape), list(shape)))
        self.used.add(key)
        return ref


def _lseg_key(key):
    """LSeg keys under any wrapper (``net.``, ``lseg_model.``, ``model.net.`` ...) -> the
    LSegNet layout (``pretrained.*``, ``scratch.*``, ``clip_pretrained.*``)."""
    parts = key.split(".")
    for i, p in enumerate(parts):
        if p in ("pretrained", "scratch", "clip_pretrained"):
            return ".".join(parts[i:])
    return key


_CLIP_TEXT_ROOTS = ("token_embedding.", "positional_embedding", "transformer.", "ln_final.",
                    "text_projection")


def _open(path, what):
    try:
        try:
            return open_checkpoint(path)
        except CheckpointError as e:
            if what == "--clip" and "TorchScript" in str(e):  # OpenAI's ViT-B-32.pt
                return open_torchscript(path)
            raise
    except CheckpointError as e:
        raise ConvertError(str(e)) from None
    except OSError as e:
        raise ConvertError("cannot read %s %s: %s" % (what, path, e.strerror or e)) from None


class Inputs:
    def __init__(self):
        self.spar = Source("spar")
        self.dino = Source("dino")
        self.lseg = Source("lseg")
        self.clip = Source("clip")
        self.sam2 = Source("sam2")  # --sam2: the mask refinement's checkpoint (sam2_plan)
        self.dropped = {}          # "file: key" -> reason
        self.dino_norm = {}        # "mean"/"std" -> TensorRef (SPAR's DINOv3 wrapper buffers)
        self.files = []            # (role, path, bytes)
        self.checkpoints = []
        self.source_of = {}        # component -> description

    def drop(self, path, key, reason):
        self.dropped["%s: %s" % (os.path.basename(path), key)] = reason

    def close(self):
        for c in self.checkpoints:
            c.close()


def read_inputs(args):
    inp = Inputs()
    try:
        _read_inputs(inp, args)
    except BaseException:
        inp.close()
        raise
    return inp


def _read_inputs(inp, args):
    ck = _open(args.checkpoint, "checkpoint")
    inp.checkpoints.append(ck)
    inp.files.append(("spar", args.checkpoint, os.path.getsize(args.checkpoint)))
    path = args.checkpoint
    for k in sorted(ck.extra):
        inp.drop(path, "<%s>" % k, "training state (not a model tensor)")
    for k in sorted(ck.skipped):
        inp.drop(path, "<%s>" % k, "training state (not read)")
    spar_dino, spar_lseg = {}, {}
    for key, ref in ck.state_dict.items():
        if key.startswith("spar_loss_computer."):
            inp.drop(path, key, "training only (perceptual loss)")
        elif key in ("_dino_v3.mean", "_dino_v3.std"):
            inp.dino_norm[key.split(".")[-1]] = (ref, key)
        elif key.startswith("_dino_v3.model."):
            spar_dino[key[len("_dino_v3.model."):]] = (ref, key)
        elif key.startswith("_dino_v3."):
            inp.drop(path, key, "unknown DINOv3 wrapper tensor, not used")
        elif key.startswith("lseg_model."):
            spar_lseg[key] = ref
        else:
            inp.spar.add(key, ref, path, key)
    inp.source_of["spar"] = path
    inp.spar.where = (os.path.basename(path), "")

    # DINOv3: --dino (released bare state_dict) overrides _dino_v3.* of the checkpoint
    if args.dino:
        dk = _open(args.dino, "--dino")
        inp.checkpoints.append(dk)
        inp.files.append(("dino", args.dino, os.path.getsize(args.dino)))
        keys = dk.state_dict
        pre = ""
        if not any(k.startswith("blocks.") for k in keys):
            for cand in ("_dino_v3.model.", "model.", "backbone.", "module."):
                if any(k.startswith(cand + "blocks.") for k in keys):
                    pre = cand
                    break
        for key, ref in keys.items():
            k = key[len(pre):] if pre and key.startswith(pre) else key
            inp.dino.add(k, ref, args.dino, key)
        for k in dk.extra:
            inp.drop(args.dino, "<%s>" % k, "not a model tensor")
        for k, (_, stored) in spar_dino.items():
            inp.drop(path, stored, "overridden by --dino")
        inp.source_of["dino"] = args.dino
        inp.dino.where = (os.path.basename(args.dino), pre)
    elif spar_dino:
        for k, (ref, stored) in spar_dino.items():
            inp.dino.add(k, ref, path, stored)
        inp.source_of["dino"] = path + " (_dino_v3.model.*)"
        inp.dino.where = (os.path.basename(path), "_dino_v3.model.")

    # LSeg: --lseg (Lightning checkpoint, net.*) overrides lseg_model.*; it also carries CLIP
    lseg_from, lseg_path = {}, None
    if args.lseg:
        lk = _open(args.lseg, "--lseg")
        inp.checkpoints.append(lk)
        inp.files.append(("lseg", args.lseg, os.path.getsize(args.lseg)))
        lseg_from, lseg_path = lk.state_dict, args.lseg
        for k in lk.extra:
            inp.drop(args.lseg, "<%s>" % k, "training state (not a model tensor)")
        for k in spar_lseg:
            inp.drop(path, k, "overridden by --lseg")
        inp.source_of["lseg"] = args.lseg
    elif spar_lseg:
        lseg_from, lseg_path = spar_lseg, path
        inp.source_of["lseg"] = path + " (lseg_model.*)"
    clip_from_lseg = {}
    for key, ref in lseg_from.items():
        k = _lseg_key(key)
        if k.startswith("clip_pretrained."):
            sub = k[len("clip_pretrained."):]
            if sub.startswith(_CLIP_TEXT_ROOTS):
                clip_from_lseg[sub] = (ref, key)
            elif sub.startswith("visual."):
                inp.drop(lseg_path, key, "CLIP visual tower: never used")
            else:
                inp.drop(lseg_path, key, "CLIP tensor not used (LSeg's logit scale is fixed)")
        else:
            inp.lseg.add(k, ref, lseg_path, key)
            if inp.lseg.where is None:
                inp.lseg.where = (os.path.basename(lseg_path), key[: len(key) - len(k)])

    # CLIP: --clip (OpenAI's state_dict) overrides the CLIP inside the LSeg checkpoint
    if args.clip:
        kk = _open(args.clip, "--clip")
        inp.checkpoints.append(kk)
        inp.files.append(("clip", args.clip, os.path.getsize(args.clip)))
        for key, ref in kk.state_dict.items():
            k = key
            parts = k.split(".")
            if "clip_pretrained" in parts:
                k = ".".join(parts[parts.index("clip_pretrained") + 1:])
            if k.startswith(_CLIP_TEXT_ROOTS):
                inp.clip.add(k, ref, args.clip, key)
            elif k.startswith("visual."):
                inp.drop(args.clip, key, "CLIP visual tower: never used")
            else:
                inp.drop(args.clip, key, "CLIP tensor not used by the text encoder")
        for k, (_, stored) in clip_from_lseg.items():
            inp.drop(lseg_path, stored, "overridden by --clip")
        inp.source_of["clip"] = args.clip
        inp.clip.where = (os.path.basename(args.clip), "")
    elif clip_from_lseg:
        for k, (ref, stored) in clip_from_lseg.items():
            inp.clip.add(k, ref, lseg_path, stored)
        inp.source_of["clip"] = lseg_path + " (clip_pretrained.*)"
        stored = next(iter(clip_from_lseg.values()))[1]
        inp.clip.where = (os.path.basename(lseg_path),
                          stored[: stored.index("clip_pretrained.") + len("clip_pretrained.")])

    if getattr(args, "sam2", None):
        sk = _open(args.sam2, "--sam2")
        inp.checkpoints.append(sk)
        inp.files.append(("sam2", args.sam2, os.path.getsize(args.sam2)))
        for key, ref in sk.state_dict.items():
            inp.sam2.add(key, ref, args.sam2, key)
        for k in sk.extra:
            inp.drop(args.sam2, "<%s>" % k, "not a model tensor")
        inp.source_of["sam2"] = args.sam2
        inp.sam2_config_spec = getattr(args, "sam2_config", None)
        inp.sam2.where = (os.path.basename(args.sam2), "")
    elif getattr(args, "sam2_config", None):
        raise ConvertError("--sam2-config needs --sam2 (the SAM2.1 checkpoint)")

    bpe = args.bpe or (DEFAULT_BPE if inp.clip else None)
    if bpe:
        try:
            with open(bpe, "rb") as f:
                data = f.read()
        except OSError as e:
            raise ConvertError("cannot read --bpe %s: %s" % (bpe, e.strerror or e)) from None
        try:
            text = gzip.decompress(data)
        except (OSError, EOFError, zlib.error) as e:
            raise ConvertError("--bpe %s is not a gzip file (%s)" % (bpe, e)) from None
        if b"#version" not in text.split(b"\n", 1)[0]:
            raise ConvertError("--bpe %s does not look like CLIP's merges table (no #version "
                               "line)" % bpe)
        inp.bpe = np.frombuffer(data, dtype=np.uint8)
        inp.files.append(("bpe", bpe, len(data)))
    else:
        inp.bpe = None


# ============================================================================ configuration
def _count(src, stack):
    """Number of layers of `stack`: 1 + the largest index i of any tensor `<stack>.<i>.*`
    (the plan then requires every tensor of every layer, so a hole is a missing tensor)."""
    rx = re.compile("^" + re.escape(stack) + r"\.(\d+)\.")
    idx = [int(m.group(1)) for m in (rx.match(k) for k in src.tensors) if m]
    return max(idx) + 1 if idx else 0


# stacks whose layer count the configuration fixes: a layer beyond it is an error
_STACKS = {
    "spar": ("transformer_encoder", "transformer_encoder_geom", "transformer_decoder",
             "cv_drp.estimator.transformer_layers"),
    "dino": ("blocks",),
    "clip": ("transformer.resblocks",),
}


def _spar_shapes(inp):
    """name -> shape of the checkpoint's SPAR tensors."""
    return {k: tuple(ref.shape) for k, ref in inp.spar.tensors.items()}


def _shape(src, key, ndim=None):
    ref = src.tensors.get(key)
    if ref is None:
        raise ConvertError("missing tensor %r (%s weights): cannot infer the configuration"
                           % (PREFIX[src.component] + key, src.component))
    if ndim is not None and len(ref.shape) != ndim:
        raise ConvertError("tensor %r (%s) has shape %s, expected %d dimensions"
                           % (src.stored(key), src.origin[key].split(":")[0], list(ref.shape), ndim))
    return tuple(ref.shape)


def _square_patch(n, channels, key, src):
    p = math.isqrt(max(n // channels, 0))
    if p * p * channels != n:
        raise ConvertError("tensor %r has %d input features: not patch*patch*%d"
                           % (src.stored(key), n, channels))
    return p


def _match_preset(name, sizes):
    for preset in ("full", "tiny"):
        base = backbone_config(name, preset)
        if all(base.get(k) == v for k, v in sizes.items()):
            return base, preset
    return None, None


def infer_config(inp, notes):
    s = inp.spar
    c = SparConfig()
    c.scene_tokens, c.d = _shape(s, "scene_code", 2)
    c.pose_tokens = _shape(s, "cam_code", 2)[0]
    if "transformer_encoder.0.attn.q_norm.weight" in s:
        c.use_qk_norm = True
        c.d_head = _shape(s, "transformer_encoder.0.attn.q_norm.weight", 1)[0]
        notes.append("D=%d, d_head=%d (%d heads) from scene_code and the RMSNorm q_norm weight"
                     % (c.d, c.d_head, c.d // max(c.d_head, 1)))
    else:
        c.use_qk_norm = False
        notes.append("no QK-norm weights: d_head=%d ASSUMED (official default)" % c.d_head)
    c.encoder_n_layer = _count(s, "transformer_encoder")
    c.encoder_geom_n_layer = _count(s, "transformer_encoder_geom")
    c.decoder_n_layer = _count(s, "transformer_decoder")
    c.cv_drp_n_layer = _count(s, "cv_drp.estimator.transformer_layers")
    if c.cv_drp_n_layer:
        dh = _shape(s, "cv_drp.estimator.transformer_layers.0.attn.q_norm.weight", 1)[0]
        c.cv_drp_n_heads = c.d // dh if dh and c.d % dh == 0 else 0
    notes.append("layers: pose encoder %d, scene encoder %d, decoder %d, CV-DRP %d (%d heads)"
                 % (c.encoder_n_layer, c.encoder_geom_n_layer, c.decoder_n_layer,
                    c.cv_drp_n_layer, c.cv_drp_n_heads))
    notes.append("scene tokens %d, camera tokens %d" % (c.scene_tokens, c.pose_tokens))
    n_img = _shape(s, "image_tokenizer.1.weight", 2)[1]
    c.patch_size = _square_patch(n_img, c.image_channels, "image_tokenizer.1.weight", s)
    n_ray = _shape(s, "target_pose_tokenizer.1.weight", 2)[1]
    if n_ray % (c.patch_size ** 2):
        raise ConvertError("tensor 'target_pose_tokenizer.1.weight' has %d input features: not a "
                           "multiple of patch*patch=%d" % (n_ray, c.patch_size ** 2))
    c.ray_channels = n_ray // c.patch_size ** 2
    notes.append("patch %d from image_tokenizer.1.weight; %d ray channels"
                 % (c.patch_size, c.ray_channels))
    n_pose = _shape(s, "pose_predictor.rel_head.2.weight", 2)[0]
    if n_pose not in (9, 7):
        raise ConvertError("tensor 'pose_predictor.rel_head.2.weight' has %d outputs: neither "
                           "9 (6D rotation + t) nor 7 (quaternion + t)" % n_pose)
    c.pose_representation = "6d" if n_pose == 9 else "quat"
    c.input_with_pe = any(k.startswith(("pe_embedder.", "temporal_pe_embedder."))
                          for k in s.tensors)
    if "log_plucker_scale" in s:
        c.plucker_norm_mode = "learnable"
    c.use_lseg = any(k.startswith(("semantic_", "target_pose_tokenizer_semantic."))
                     for k in s.tensors)
    if c.use_lseg:
        c.semantic_dim = _shape(s, "semantic_proj.weight", 2)[1] - 6
        c.semantic_hidden = _shape(s, "semantic_feature_expansion.1.weight", 4)[1]
        notes.append("use_lseg: semantic tensors present; semantic dim %d, hidden %d"
                     % (c.semantic_dim, c.semantic_hidden))
    else:
        notes.append("use_lseg false: no semantic tensors")
    notes.append("pose %s, input_with_pe %s, plucker normalization %s"
                 % (c.pose_representation, c.input_with_pe, c.plucker_norm_mode))
    notes.append("not in the tensors, official defaults: input_masking_mode %s, canonical %s, "
                 "semantic_loss_weight %g; views %d (%d inputs)"
                 % (c.input_masking_mode, c.canonical, c.semantic_loss_weight, c.num_views,
                    c.num_input_views))

    # DINOv3
    sizes, flags, base, preset = dino_from_tensors(inp)
    c.dino = base if base is not None else dict(resolve_config("dino", {}), arch="custom", **sizes)
    c.dino.update(flags)
    notes.append("DINOv3 (%s): %s%s" % (inp.source_of["dino"], _dino_text(sizes),
                                        ", preset %s" % preset if preset else ""))

    # LSeg
    if c.use_lseg:
        lg = inp.lseg
        if not lg:
            raise ConvertError("the checkpoint has a semantic branch (semantic_proj) but no LSeg "
                               "weights: give --lseg LSEG.ckpt")
        w = _shape(lg, "pretrained.model.cls_token")[-1]
        pp = _shape(lg, "pretrained.model.patch_embed.proj.weight", 4)[-1]
        npos = _shape(lg, "pretrained.model.pos_embed", 3)[1] - 1
        g = math.isqrt(max(npos, 0))
        if g * g != npos:
            raise ConvertError("tensor 'pretrained.model.pos_embed' has %d patch positions: not "
                               "a square grid" % npos)
        sizes = {"width": w, "depth": _count(lg, "pretrained.model.blocks"),
                 "patch_size": pp, "pretrain_img_size": g * pp,
                 "mlp_ratio": _shape(lg, "pretrained.model.blocks.0.mlp.fc1.weight", 2)[0] / w,
                 "reassemble": [_shape(lg, "pretrained.act_postprocess%d.3.weight" % i, 4)[0]
                                for i in range(1, 5)],
                 "features": _shape(lg, "scratch.layer1_rn.weight", 4)[0],
                 "feature_dim": _shape(lg, "scratch.head1.weight", 4)[0],
                 "use_bn": "scratch.refinenet1.resConfUnit2.bn1.weight" in lg}
        if "pretrained.model.head.weight" in lg:
            sizes["num_classes"] = _shape(lg, "pretrained.model.head.weight", 2)[0]
        base, preset = _match_preset("lseg", sizes)
        if base is not None:
            c.lseg = base
            how = "preset %s" % preset
        else:
            c.lseg = resolve_config("lseg", dict(sizes, backbone="custom", num_heads=w // 64))
            how = "heads %d ASSUMED (width/64: timm's qkv does not show them)" % (w // 64)
        notes.append("LSeg (%s): width %d, depth %d, patch %d, reassemble %s, features %d, "
                     "output %d, hooks %s, %s" % (inp.source_of["lseg"], w, sizes["depth"], pp,
                                                  sizes["reassemble"], sizes["features"],
                                                  sizes["feature_dim"], c.lseg["hooks"], how))
    # CLIP text
    k = inp.clip
    if k:
        te = _shape(k, "token_embedding.weight", 2)
        sizes = {"width": te[1], "vocab_size": te[0],
                 "layers": _count(k, "transformer.resblocks"),
                 "context_length": _shape(k, "positional_embedding", 2)[0],
                 "embed_dim": _shape(k, "text_projection", 2)[1]}
        base, preset = _match_preset("clip", sizes)
        if base is not None:
            c.clip = base
            how = "heads %d (preset %s)" % (base["heads"], preset)
        else:
            c.clip = dict(resolve_config("clip", {}), heads=te[1] // 64, **sizes)
            how = "heads %d ASSUMED (width/64, OpenAI's rule)" % (te[1] // 64)
        notes.append("CLIP text (%s): width %d, layers %d, context %d, vocab %d, embed %d, %s"
                     % (inp.source_of["clip"], te[1], sizes["layers"], sizes["context_length"],
                        sizes["vocab_size"], sizes["embed_dim"], how))
    else:
        notes.append("no CLIP text encoder weights (labels unavailable); clip sizes left at the "
                     "official defaults")
    return c


def dino_from_tensors(inp):
    """DINOv3's sizes as its tensors show them: (sizes, bias flags, matching preset dictionary
    or None, preset name or None). Heads come from RoPE: rope_embed.periods holds head_dim / 4
    values, so heads = width / (4 * len(periods))."""
    d = inp.dino
    if not d:
        raise ConvertError("no DINOv3 weights: the checkpoint has no _dino_v3.model.* tensors; "
                           "give --dino DINO.pth")
    e = _shape(d, "cls_token")[-1]
    pe = _shape(d, "patch_embed.proj.weight", 4)
    heads_q = _shape(d, "rope_embed.periods", 1)[0]
    if not heads_q or e % (4 * heads_q):
        raise ConvertError("DINOv3 (%s): width %d is not a multiple of 4 x its %d RoPE periods "
                           "(rope_embed.periods): no whole number of heads"
                           % (inp.source_of["dino"], e, heads_q))
    sizes = {"embed_dim": e, "depth": _count(d, "blocks"),
             "patch_size": pe[-1], "in_chans": pe[1],
             "n_storage_tokens": _shape(d, "storage_tokens", 3)[1] if "storage_tokens" in d else 0,
             "num_heads": e // (4 * heads_q),
             "ffn_ratio": _shape(d, "blocks.0.mlp.fc1.weight", 2)[0] / e}
    flags = {"qkv_bias": "blocks.0.attn.qkv.bias" in d,
             "mask_k_bias": "blocks.0.attn.qkv.bias_mask" in d,
             "proj_bias": "blocks.0.attn.proj.bias" in d,
             "ffn_bias": "blocks.0.mlp.fc1.bias" in d}
    base, preset = _match_preset("dino", sizes)
    return sizes, flags, base, preset


def _dino_text(sizes):
    return ("width %d, depth %d, heads %d (from rope_embed.periods), patch %d, %d register tokens"
            % (sizes["embed_dim"], sizes["depth"], sizes["num_heads"], sizes["patch_size"],
               sizes["n_storage_tokens"]))


def dino_sizes_from_tensors(cfg, inp):
    """With --config: DINOv3's architecture is that of the DINOv3 file, not what the YAML names
    (spar.yaml only says arch vitb16 / embed_dim, and its defaults are ViT-B's 12 heads and 12
    blocks). The tensors win; the note (None when the configuration agrees) says what changed.
    A DINOv3 width other than D stays as the configuration says, so that the plan names the first
    tensor that does not fit (the SPAR checkpoint's own, when the configuration's D is wrong)."""
    sizes, flags, base, _ = dino_from_tensors(inp)
    if sizes["embed_dim"] != cfg.d:
        del sizes["embed_dim"]
        base = None
    changed = ["%s %s -> %s" % (k, cfg.dino.get(k), v) for k, v in sizes.items()
               if cfg.dino.get(k) != v]
    cfg.dino.update(sizes)
    cfg.dino.update(flags)
    if changed:
        cfg.dino["arch"] = base["arch"] if base is not None else "custom"
        return ("DINOv3 sizes from the tensors of %s, not the configuration's: %s"
                % (inp.source_of["dino"], ", ".join(changed)))
    return None


def parse_size(text):
    """--size HxW -> (height, width); argparse reports ArgumentTypeError as a usage error.
    Whether the patch size divides it is judged with the configuration (SparConfig.validate)."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() and int(p) > 0 for p in parts):
        raise argparse.ArgumentTypeError("expected HEIGHTxWIDTH in pixels (e.g. 128x128), got %r"
                                         % text)
    return int(parts[0]), int(parts[1])


def load_config(path):
    """(SparConfig, (height, width) the file names or None)."""
    try:
        data = read_config_file(path)
        size = stated_image_size(data)
        cfg = SparConfig.from_dict(data)
    except OSError as e:
        raise ConvertError("cannot read --config %s: %s" % (path, e.strerror or e)) from None
    except ImportError:
        raise ConvertError("--config %s: reading YAML needs python3-yaml; give JSON" % path) \
            from None
    except (ValueError, TypeError, KeyError, AssertionError, AttributeError) as e:
        raise ConvertError("--config %s: %s" % (path, _one_line(e) or type(e).__name__)) from None
    except Exception as e:  # yaml.YAMLError and friends
        raise ConvertError("--config %s: %s" % (path, _one_line(e))) from None
    for name in ("dino", "lseg", "clip"):
        setattr(cfg, name, resolve_config(name, getattr(cfg, name)))
    return cfg, size


def _one_line(e):
    return " ".join(str(e).split())


# ============================================================================ the plan
class Entry:
    __slots__ = ("name", "shape", "dtype", "make", "kind", "sources", "quant")

    def __init__(self, name, shape, make, kind, sources):
        self.name, self.shape, self.make = name, tuple(shape), make
        self.kind, self.sources = kind, sources
        self.dtype = "F32"
        self.quant = None  # "q8" / "q4": stored as codes + scales (quantize.py)


def _to_f64(ref):
    return ref.numpy().astype(np.float64)


class Planner:
    def __init__(self, inp):
        self.inp = inp
        self.entries = []
        self.folded_away = {}   # (component, key) -> output it was folded into

    def keep(self, src, key, shape):
        ref = src.get(key, shape)
        self.entries.append(Entry(PREFIX[src.component] + key, shape, ref.numpy, "kept",
                                  [src.origin[key]]))

    def bn_fold(self, src, conv, bn, w_shape, cout, transposed, has_bias):
        """conv (weight [, bias]) followed by eval-mode BatchNorm `bn`: two entries, the folded
        weight and a bias (created if the conv had none)."""
        w = src.get(conv + ".weight", w_shape)
        b = src.get(conv + ".bias", (cout,)) if has_bias else None
        g = src.get(bn + ".weight", (cout,))
        beta = src.get(bn + ".bias", (cout,))
        mean = src.get(bn + ".running_mean", (cout,))
        var = src.get(bn + ".running_var", (cout,))
        if bn + ".num_batches_tracked" in src:
            src.used.add(bn + ".num_batches_tracked")
            self.folded_away[(src.component, bn + ".num_batches_tracked")] = None

        def scale():
            v = _to_f64(var)
            if np.any(v < 0):
                raise ConvertError("tensor %r has negative variances" % src.stored(bn + ".running_var"))
            return _to_f64(g) / np.sqrt(v + BN_EPS)

        def weight():
            s = scale()
            ww = _to_f64(w)
            return ww * (s[None, :, None, None] if transposed else s[:, None, None, None])

        def bias():
            s = scale()
            b0 = _to_f64(b) if b is not None else 0.0
            return (b0 - _to_f64(mean)) * s + _to_f64(beta)

        names = [src.origin[k] for k in ([conv + ".weight"] + ([conv + ".bias"] if b else [])
                                         + [bn + x for x in (".weight", ".bias", ".running_mean",
                                                             ".running_var")])]
        p = PREFIX[src.component]
        self.entries.append(Entry(p + conv + ".weight", w_shape, weight, "folded", names))
        self.entries.append(Entry(p + conv + ".bias", (cout,), bias, "folded" if b else "created",
                                  names))
        for x in (".weight", ".bias", ".running_mean", ".running_var"):
            self.folded_away[(src.component, bn + x)] = p + conv

    # ---------------------------------------------------------------- SPAR's own tensors
    def spar(self, c):
        s, d, p = self.inp.spar, c.d, c.patch_size
        k = self.keep
        k(s, "scene_code", (c.scene_tokens, d))
        k(s, "cam_code", (c.pose_tokens, d))
        if c.input_masking_mode == "soft_with_pe":
            k(s, "mask_token", (1, 1, d))
        if c.input_masking_mode == "learnable_indicator":
            k(s, "static_indicator", (1, 1, d))
            k(s, "dynamic_indicator", (1, 1, d))
        k(s, "image_tokenizer.1.weight", (d, p * p * c.image_channels))
        if c.input_with_pe:
            for m in ("pe_embedder", "temporal_pe_embedder"):
                for i in (0, 2):
                    k(s, "%s.%d.weight" % (m, i), (d, d))
                    k(s, "%s.%d.bias" % (m, i), (d,))
        for stack, n, dh in (("transformer_encoder", c.encoder_n_layer, c.d_head),
                             ("transformer_encoder_geom", c.encoder_geom_n_layer, c.d_head),
                             ("transformer_decoder", c.decoder_n_layer, c.d_head),
                             ("cv_drp.estimator.transformer_layers", c.cv_drp_n_layer,
                              c.cv_drp_head_dim)):
            qk = c.use_qk_norm or stack.startswith("cv_drp")
            for i in range(n):
                b = "%s.%d." % (stack, i)
                k(s, b + "norm1.weight", (d,))
                k(s, b + "attn.to_qkv.weight", (3 * d, d))
                if qk:
                    k(s, b + "attn.q_norm.weight", (dh,))
                    k(s, b + "attn.k_norm.weight", (dh,))
                k(s, b + "attn.fc.weight", (d, d))
                k(s, b + "norm2.weight", (d,))
                k(s, b + "mlp.mlp.0.weight", (4 * d, d))
                k(s, b + "mlp.mlp.2.weight", (d, 4 * d))
            if stack == "transformer_encoder_geom":
                k(s, "decoder_ln.weight", (d,))
        n_pose = (6 if c.pose_representation == "6d" else 4) + 3
        for head, din, dout in (("rel_head", 2 * d, n_pose), ("canonical_k_head", d, 1)):
            k(s, "pose_predictor.%s.0.weight" % head, (d, din))
            k(s, "pose_predictor.%s.0.bias" % head, (d,))
            k(s, "pose_predictor.%s.2.weight" % head, (dout, d))
            k(s, "pose_predictor.%s.2.bias" % head, (dout,))
        k(s, "target_pose_tokenizer.1.weight", (d, p * p * c.ray_channels))
        k(s, "target_pose_tokenizer2.1.weight", (d, p * p * c.ray_channels))
        k(s, "mlp_fuse.0.weight", (2 * d,))
        k(s, "mlp_fuse.1.weight", (d, 2 * d))
        k(s, "mlp_fuse.1.bias", (d,))
        k(s, "mlp_fuse.3.weight", (d, d))
        k(s, "mlp_fuse.3.bias", (d,))
        k(s, "image_token_decoder.0.weight", (d,))
        k(s, "image_token_decoder.1.weight", (p * p * 3, d))
        k(s, "view_type_embedding.weight", (2, d))
        e = "cv_drp.estimator."
        dd = c.dino_width
        k(s, e + "fusion_mlp.net.0.weight", (2 * d, dd + 2 * d))
        k(s, e + "fusion_mlp.net.0.bias", (2 * d,))
        k(s, e + "fusion_mlp.net.2.weight", (d, 2 * d))
        k(s, e + "fusion_mlp.net.2.bias", (d,))
        t = e + "dpt_decoder."
        ch = (256, 128, 64, 32)
        self.bn_fold(s, t + "project.0", t + "project.1", (ch[0], d, 1, 1), ch[0], False, True)
        for i in range(3):
            u = "%sup_blocks.%d." % (t, i)
            self.bn_fold(s, u + "0", u + "1", (ch[i], ch[i + 1], 2, 2), ch[i + 1], True, True)
            self.bn_fold(s, u + "3", u + "4", (ch[i + 1], ch[i + 1], 3, 3), ch[i + 1], False, True)
        self.bn_fold(s, t + "final_up.0", t + "final_up.1", (ch[3], 16, 2, 2), 16, True, True)
        k(s, t + "head.weight", (1, 16, 1, 1))
        k(s, t + "head.bias", (1,))
        if c.use_lseg:
            k(s, "semantic_proj.weight", (d, c.semantic_dim + 6))
            k(s, "semantic_proj.bias", (d,))
            k(s, "target_pose_tokenizer_semantic.1.weight", (d, p * p * c.ray_channels))
            k(s, "semantic_token_decoder.0.weight", (d,))
            k(s, "semantic_token_decoder.1.weight", (2 * d, d))
            k(s, "semantic_token_decoder.3.weight", (4 * d, 2 * d))
            k(s, "semantic_token_decoder.5.weight", (p * p * c.semantic_hidden, 4 * d))
            k(s, "semantic_feature_expansion.1.weight", (c.semantic_dim, c.semantic_hidden, 1, 1))
            k(s, "semantic_feature_expansion.1.bias", (c.semantic_dim,))
        if c.plucker_norm_mode == "learnable":
            k(s, "log_plucker_scale", (1,))

    # ---------------------------------------------------------------- DINOv3
    def dino(self, c):
        s, cfg = self.inp.dino, c.dino
        if not s:
            raise ConvertError("no DINOv3 weights: the checkpoint has no _dino_v3.model.* "
                               "tensors; give --dino DINO.pth")
        e, depth, nh = int(cfg["embed_dim"]), int(cfg["depth"]), int(cfg["num_heads"])
        pp, r = int(cfg["patch_size"]), int(cfg.get("n_storage_tokens", 0))
        hid = int(round(e * float(cfg.get("ffn_ratio", 4.0))))
        if nh <= 0 or e % (4 * nh):
            raise ConvertError("DINOv3 width %d is not divisible by 4 x heads (%d)" % (e, nh))
        k = self.keep
        k(s, "cls_token", (1, 1, e))
        if r:
            k(s, "storage_tokens", (1, r, e))
        k(s, "patch_embed.proj.weight", (e, int(cfg.get("in_chans", 3)), pp, pp))
        k(s, "patch_embed.proj.bias", (e,))
        k(s, "rope_embed.periods", (e // nh // 4,))
        for i in range(depth):
            b = "blocks.%d." % i
            k(s, b + "norm1.weight", (e,))
            k(s, b + "norm1.bias", (e,))
            k(s, b + "attn.qkv.weight", (3 * e, e))
            if cfg.get("qkv_bias", True):
                if cfg.get("mask_k_bias", True) and b + "attn.qkv.bias_mask" in s:
                    bias = s.get(b + "attn.qkv.bias", (3 * e,))
                    mask = s.get(b + "attn.qkv.bias_mask", (3 * e,))
                    self.entries.append(Entry(
                        "dino." + b + "attn.qkv.bias", (3 * e,),
                        (lambda bias=bias, mask=mask: _to_f64(bias) * _to_f64(mask)), "folded",
                        [s.origin[b + "attn.qkv.bias"], s.origin[b + "attn.qkv.bias_mask"]]))
                    self.folded_away[("dino", b + "attn.qkv.bias_mask")] = "dino." + b + "attn.qkv.bias"
                else:
                    k(s, b + "attn.qkv.bias", (3 * e,))
            k(s, b + "attn.proj.weight", (e, e))
            if cfg.get("proj_bias", True):
                k(s, b + "attn.proj.bias", (e,))
            k(s, b + "ls1.gamma", (e,))
            k(s, b + "norm2.weight", (e,))
            k(s, b + "norm2.bias", (e,))
            k(s, b + "mlp.fc1.weight", (hid, e))
            k(s, b + "mlp.fc2.weight", (e, hid))
            if cfg.get("ffn_bias", True):
                k(s, b + "mlp.fc1.bias", (hid,))
                k(s, b + "mlp.fc2.bias", (e,))
            k(s, b + "ls2.gamma", (e,))
        k(s, "norm.weight", (e,))
        k(s, "norm.bias", (e,))

    # ---------------------------------------------------------------- LSeg
    def lseg(self, c):
        s, cfg = self.inp.lseg, c.lseg
        if not s:
            raise ConvertError("the configuration uses LSeg (use_lseg) but no LSeg weights were "
                               "found: give --lseg LSEG.ckpt")
        w, pp = int(cfg["width"]), int(cfg["patch_size"])
        g = int(cfg["pretrain_img_size"]) // pp
        hid = int(round(w * float(cfg.get("mlp_ratio", 4.0))))
        hooks = [int(h) for h in cfg["hooks"]]
        r = [int(v) for v in cfg["reassemble"]]
        f, out = int(cfg["features"]), int(cfg["feature_dim"])
        bn = bool(cfg.get("use_bn", True))
        k = self.keep
        m = "pretrained.model."
        k(s, m + "cls_token", (1, 1, w))
        k(s, m + "pos_embed", (1, 1 + g * g, w))
        k(s, m + "patch_embed.proj.weight", (w, 3, pp, pp))
        k(s, m + "patch_embed.proj.bias", (w,))
        for i in range(max(hooks) + 1):
            b = "%sblocks.%d." % (m, i)
            for n in ("norm1", "norm2"):
                k(s, b + n + ".weight", (w,))
                k(s, b + n + ".bias", (w,))
            k(s, b + "attn.qkv.weight", (3 * w, w))
            k(s, b + "attn.qkv.bias", (3 * w,))
            k(s, b + "attn.proj.weight", (w, w))
            k(s, b + "attn.proj.bias", (w,))
            k(s, b + "mlp.fc1.weight", (hid, w))
            k(s, b + "mlp.fc1.bias", (hid,))
            k(s, b + "mlp.fc2.weight", (w, hid))
            k(s, b + "mlp.fc2.bias", (w,))
        tails = {1: ("convT", 4), 2: ("convT", 2), 3: None, 4: ("conv", 3)}
        for i in range(1, 5):
            a = "pretrained.act_postprocess%d." % i
            k(s, a + "0.project.0.weight", (w, 2 * w))
            k(s, a + "0.project.0.bias", (w,))
            k(s, a + "3.weight", (r[i - 1], w, 1, 1))
            k(s, a + "3.bias", (r[i - 1],))
            if tails[i]:
                ks = tails[i][1]
                k(s, a + "4.weight", (r[i - 1], r[i - 1], ks, ks))
                k(s, a + "4.bias", (r[i - 1],))
        for i in range(1, 5):
            k(s, "scratch.layer%d_rn.weight" % i, (f, r[i - 1], 3, 3))
        for i in range(1, 5):
            rn = "scratch.refinenet%d." % i
            k(s, rn + "out_conv.weight", (f, f, 1, 1))
            k(s, rn + "out_conv.bias", (f,))
            for u in ((2,) if i == 4 else (1, 2)):  # refinenet4 has one input: no resConfUnit1
                for j in (1, 2):
                    conv = "%sresConfUnit%d.conv%d" % (rn, u, j)
                    if bn:
                        self.bn_fold(s, conv, "%sresConfUnit%d.bn%d" % (rn, u, j),
                                     (f, f, 3, 3), f, False, False)
                    else:
                        k(s, conv + ".weight", (f, f, 3, 3))
                        k(s, conv + ".bias", (f,))
        k(s, "scratch.head1.weight", (out, f, 1, 1))
        k(s, "scratch.head1.bias", (out,))

    # ---------------------------------------------------------------- CLIP text
    def clip(self, c):
        s, cfg = self.inp.clip, c.clip
        w, n, v = int(cfg["width"]), int(cfg["context_length"]), int(cfg["vocab_size"])
        k = self.keep
        k(s, "token_embedding.weight", (v, w))
        k(s, "positional_embedding", (n, w))
        for i in range(int(cfg["layers"])):
            b = "transformer.resblocks.%d." % i
            for ln in ("ln_1", "ln_2"):
                k(s, b + ln + ".weight", (w,))
                k(s, b + ln + ".bias", (w,))
            k(s, b + "attn.in_proj_weight", (3 * w, w))
            k(s, b + "attn.in_proj_bias", (3 * w,))
            k(s, b + "attn.out_proj.weight", (w, w))
            k(s, b + "attn.out_proj.bias", (w,))
            k(s, b + "mlp.c_fc.weight", (4 * w, w))
            k(s, b + "mlp.c_fc.bias", (4 * w,))
            k(s, b + "mlp.c_proj.weight", (w, 4 * w))
            k(s, b + "mlp.c_proj.bias", (w,))
        k(s, "ln_final.weight", (w,))
        k(s, "ln_final.bias", (w,))
        k(s, "text_projection", (w, int(cfg["embed_dim"])))


# reasons for source tensors the plan does not use
_DROP_RULES = [
    ("spar", re.compile(r"^cv_drp\.estimator\.(dino_proj|image_proj|ray_proj)\."),
     "CV-DRP projection never read by the forward"),
    ("spar", re.compile(r"(^|\.)num_batches_tracked$"), "BatchNorm step counter (training only)"),
    ("spar", re.compile(r"^(static|dynamic)_indicator$"),
     "used only by input_masking_mode learnable_indicator"),
    ("spar", re.compile(r"^mask_token$"), "not used by this input_masking_mode"),
    ("spar", re.compile(r"^(semantic_|target_pose_tokenizer_semantic)"),
     "semantic branch off (use_lseg false)"),
    ("spar", re.compile(r"^log_plucker_scale$"), "used only by plucker normalization learnable"),
    ("dino", re.compile(r"^mask_token$"), "masked-token pretraining only"),
    ("dino", re.compile(r"(^|\.)num_batches_tracked$"), "counter, not a weight"),
    ("lseg", re.compile(r"^pretrained\.model\.norm\."),
     "LSeg reads its hooks before the ViT's final norm"),
    ("lseg", re.compile(r"^pretrained\.model\.head\."), "timm classifier head, never used"),
    ("lseg", re.compile(r"^scratch\.refinenet4\.resConfUnit1\."),
     "refinenet4 has one input: resConfUnit1 is never called"),
    ("lseg", re.compile(r"^pretrained\.model\.blocks\.\d+\."), "ViT block after the last hook"),
    ("lseg", re.compile(r"(^|\.)num_batches_tracked$"), "BatchNorm step counter (training only)"),
    ("clip", re.compile(r"(^|\.)attn_mask$"), "causal mask (the engine builds it)"),
]


def _drop_reason(component, key):
    for comp, rx, reason in _DROP_RULES:
        if comp == component and rx.search(key):
            return reason, True
    return "not used by the engine (unknown to the converter)", False


def _count_planned(pl, src, stack):
    p = PREFIX[src.component] + stack + "."
    idx = {int(e.name[len(p):].split(".", 1)[0]) for e in pl.entries if e.name.startswith(p)}
    return max(idx) + 1 if idx else 0


def plan_sam2(inp):
    """--sam2's variant and the entries of its refinement path (sam2_plan)."""
    shapes = {k: tuple(r.shape) for k, r in inp.sam2.tensors.items()}
    try:
        cfg, how = sam2_plan.resolve(shapes, inp.source_of["sam2"], getattr(inp, "sam2_config_spec", None))
        pl = Planner(inp)
        path = inp.source_of["sam2"]
        sam2_plan.plan(inp.sam2, cfg, pl.keep, lambda key, why: inp.drop(path, key, why))
    except sam2_plan.Sam2PlanError as e:
        raise ConvertError(str(e)) from None
    return cfg, how, pl.entries


def make_plan(inp, cfg):
    pl = Planner(inp)
    pl.spar(cfg)
    pl.dino(cfg)
    if cfg.use_lseg:
        pl.lseg(cfg)
    if inp.clip:
        pl.clip(cfg)
    if inp.bpe is not None:
        data = inp.bpe
        pl.entries.append(Entry(BPE_NAME, data.shape, lambda: data, "packed",
                                [os.path.basename(inp.files[-1][1])]))
        pl.entries[-1].dtype = "U8"
    warnings = []
    for src in (inp.spar, inp.dino, inp.lseg, inp.clip):
        for key in src.tensors:
            if key in src.used and (src.component, key) not in pl.folded_away:
                continue
            if (src.component, key) in pl.folded_away:
                into = pl.folded_away[(src.component, key)]
                reason = ("folded into %s" % into) if into else "BatchNorm step counter (training only)"
            elif src.component == "lseg" and not cfg.use_lseg:
                reason = "semantic branch off (use_lseg false)"
            else:
                reason, known = _drop_reason(src.component, key)
                for stack in _STACKS.get(src.component, ()):
                    m = re.match(re.escape(stack) + r"\.(\d+)\.", key)
                    if m and int(m.group(1)) >= _count_planned(pl, src, stack):
                        raise ConvertError(
                            "tensor %r (%s): layer %s is beyond the %d layers of %s in the "
                            "configuration" % (src.stored(key), src.origin[key].split(":")[0],
                                               m.group(1), _count_planned(pl, src, stack), stack))
                if not known:
                    warnings.append(src.origin[key])
            inp.dropped[src.origin[key]] = reason
    for key in ("mean", "std"):
        if key in inp.dino_norm:
            inp.dropped[os.path.basename(inp.files[0][1]) + ": " + inp.dino_norm[key][1]] = \
                "ImageNet normalization: stored in config.dino.%s" % key
    return pl.entries, warnings


def is_matrix(name, shape):
    """The --fp16 rule: weight matrices and convolution kernels (2-D or more, named
    ``*.weight`` / ``*in_proj_weight``), CLIP's ``text_projection`` and token embedding table.
    Everything else (norms, biases, LayerScale, learned tokens and position embeddings, the
    2-row view-type embedding, RoPE periods) stays F32."""
    if len(shape) < 2:
        return False
    if name.endswith("view_type_embedding.weight"):
        return False
    if name.startswith(sam2_plan.PACKED_PREFIX) and name.endswith(("_token.weight", "_tokens.weight")):
        return False  # SAM2's learned decoder tokens (iou, mask, object-score)
    return name.endswith(".weight") or name.endswith("in_proj_weight") or \
        name.endswith("text_projection")


# The matrices --weights q8 / q4 quantize: the linear layers of the transformer blocks (attention
# projections and MLPs of SPAR's encoders, decoder and CV-DRP, DINOv3, LSeg's ViT, CLIP's text
# tower), which hold most of the parameters and reach the engine only through its GEMM. Embedding
# tables, position tables, convolution kernels, norms, biases and the small heads stay as
# --weights fp32 / fp16 would store them (FORMAT.md, "Quantized matrices").
QUANTIZED_MATRICES = re.compile(
    r"^(?:(?:transformer_encoder|transformer_encoder_geom|transformer_decoder|cv_drp\.estimator\.transformer_layers)"
    r"\.\d+\.(?:attn\.to_qkv|attn\.fc|mlp\.mlp\.\d+)\.weight"
    r"|(?:dino\.blocks|lseg\.pretrained\.model\.blocks)\.\d+\.(?:attn\.qkv|attn\.proj|mlp\.fc1|mlp\.fc2)\.weight"
    r"|clip\.transformer\.resblocks\.\d+\.(?:attn\.in_proj_weight|attn\.out_proj\.weight|mlp\.c_fc\.weight"
    r"|mlp\.c_proj\.weight)"
    # CLIP's token embedding (the embedding kernel dequantizes its rows)
    r"|clip\.token_embedding\.weight"
    # SPAR's other linear layers: the semantic head (the largest single matrix), the fusion MLPs,
    # the tokenizers and position MLPs, the RGB head
    r"|(?:semantic_token_decoder|mlp_fuse|pe_embedder|temporal_pe_embedder|image_tokenizer|target_pose_tokenizer"
    r"|target_pose_tokenizer2|target_pose_tokenizer_semantic"
    r"|cv_drp\.estimator\.fusion_mlp\.net)\.\d+\.weight"
    # LSeg's convolutions [Cout, Cin, kh, kw] (quantized as the matrix [Cout, Cin*kh*kw]; the
    # conv2d kernel dequantizes them): the 1x1 projection after each hook's readout, hook 4's
    # 3x3 stride-2 conv, the 3x3 layerN_rn and the refinenets' residual units. Not the
    # transposed convs of hooks 1 and 2 (act_postprocess1.4 / 2.4), nor the 1x1 out_conv / head.
    r"|lseg\.pretrained\.act_postprocess[1-4]\.3\.weight|lseg\.pretrained\.act_postprocess4\.4\.weight"
    r"|lseg\.scratch\.layer[1-4]_rn\.weight|lseg\.scratch\.refinenet[1-4]\.resConfUnit[12]\.conv[12]\.weight)$")


def quantized_rows(shape):
    """(N, K) of the matrix a quantized tensor is: [N, K], or [Cout, Cin*kh*kw] of a conv."""
    return int(shape[0]), int(np.prod(shape[1:], dtype=np.int64))


def is_quantized(name, shape):
    """Whether --weights q8 / q4 quantize this tensor: a 2-D block linear or a 4-D convolution
    kernel of the rule, whose rows (all but the first dimension) are whole blocks of 32."""
    return (len(shape) in (2, 4) and quantized_rows(shape)[1] % quant.BLOCK == 0
            and bool(QUANTIZED_MATRICES.match(name)))


def _quantized_specs(entry):
    """The two stored tensors of a quantized matrix: its codes (under its own name) and its
    scales (<name>.qscale), computed once for both."""
    cache = {}

    def codes_and_scales():
        if not cache:
            a = np.asarray(entry.make(), dtype=np.float64).reshape(quantized_rows(entry.shape))
            if not np.all(np.isfinite(a)):
                raise ConvertError("tensor %r has NaN or Inf values (%s)"
                                   % (entry.name, "; ".join(entry.sources)))
            cache["v"] = quant.quantize(a, entry.quant)
        return cache["v"]

    def scales():
        v = codes_and_scales()[1]
        cache.clear()
        return v

    n, k = quantized_rows(entry.shape)
    codes_shape = (n, k) if entry.quant == "q8" else (n, k // 2)
    return [TensorSpec(entry.name, "I8" if entry.quant == "q8" else "U8", codes_shape,
                       lambda: codes_and_scales()[0]),
            TensorSpec(entry.name + quant.SCALE_SUFFIX, "F32", (n, k // quant.BLOCK), scales)]


def _producer(entry):
    def make():
        a = np.asarray(entry.make())
        if entry.dtype == "U8":
            return a
        if not np.all(np.isfinite(a)):
            raise ConvertError("tensor %r has NaN or Inf values (%s)"
                               % (entry.name, "; ".join(entry.sources)))
        if entry.dtype == "F16":
            big = float(np.max(np.abs(a))) if a.size else 0.0
            if big > FP16_MAX:
                raise ConvertError("tensor %r has values up to %g, beyond float16's range; "
                                   "convert without --fp16" % (entry.name, big))
            return a.astype(np.float16)
        return a.astype(np.float32)
    return make


# ============================================================================ main
def _fmt_mb(n):
    return "%.2f MB" % (n / 1e6)


def _group(names, depth=3):
    """Collapse tensor names to module prefixes with counts, for printing."""
    out = {}
    for n in names:
        parts = n.split(": ", 1)[-1].split(".")
        key = ".".join(re.sub(r"^\d+$", "*", p) for p in parts[:-1][:depth]) or parts[-1]
        out[key] = out.get(key, 0) + 1
    return ", ".join("%s (%d)" % (k, v) if v > 1 else k for k, v in out.items())


def build_parser():
    ap = argparse.ArgumentParser(
        prog=PROG,
        description="Convert a SPAR checkpoint (plus its DINOv3, LSeg and CLIP backbones) into "
                    "the engine's packed safetensors file (format spar-vulkan, see "
                    "converter/FORMAT.md). Never imports PyTorch.")
    ap.add_argument("checkpoint", help="SPAR checkpoint (.pt): {'model': state_dict, ...} or a "
                                       "bare state_dict; or a packed model (.spar) whose model "
                                       "card --model-card replaces")
    ap.add_argument("-o", "--output", required=True, help="output file (e.g. model.spar)")
    ap.add_argument("--config", help="configuration: the official YAML (configs/spar/spar.yaml) "
                                     "or a SparConfig JSON/YAML; default: inferred from the tensors")
    ap.add_argument("--size", type=parse_size, metavar="HxW",
                    help="image size the checkpoint was trained at (height x width in pixels, "
                         "e.g. 128x128), the size spar render and spar eval default to; "
                         "default: the --config's (model.target_image), else 256x256 with a "
                         "warning (no tensor holds it)")
    ap.add_argument("--weights", choices=("fp32", "fp16", "q8", "q4"),
                    help="how weight matrices are stored: fp32 (default); fp16 (matrices and conv "
                         "kernels F16); q8 / q4 (the transformer blocks' linear layers as 8- or "
                         "4-bit codes with one float32 scale per block of 32, the rest as fp32; "
                         "converter/FORMAT.md)")
    ap.add_argument("--fp16", action="store_true",
                    help="the same as --weights fp16")
    ap.add_argument("--dino", help="DINOv3 backbone state_dict (dinov3_vitb16_pretrain_*.pth); "
                                   "default: _dino_v3.* of the checkpoint")
    ap.add_argument("--lseg", help="LSeg checkpoint (keys net.*, CLIP under net.clip_pretrained.*); "
                                   "default: lseg_model.* of the checkpoint")
    ap.add_argument("--clip", help="CLIP state_dict (OpenAI key layout; text tower is kept); "
                                   "default: the CLIP inside the LSeg checkpoint")
    ap.add_argument("--bpe", help="CLIP BPE merges table (bpe_simple_vocab_16e6.txt.gz), packed "
                                  "as the U8 tensor %s; default: the repository's copy "
                                  "(text/data/clip/) when the model has a CLIP text encoder"
                                  % BPE_NAME)
    ap.add_argument("--sam2", metavar="SAM2.pt",
                    help="SAM2.1 checkpoint (sam2.1_hiera_{t,s,b+,l}.pt, official key layout) for "
                         "the optional mask refinement: only the tensors of its path are packed")
    ap.add_argument("--sam2-config", metavar="NAME|YAML",
                    help="the SAM2.1 variant: sam2.1_hiera_t, _s, _b+, _l, or a YAML in the "
                         "official layout; default: the one --sam2's file name says, else the "
                         "official variant its tensor shapes are")
    ap.add_argument("--model-card", metavar="CARD.json",
                    help="what the model is, stored with it (spar_convert/model_card.py): e.g. "
                         "that it is a demonstration model, and its measured quality; spar render "
                         "and its index.html say it")
    ap.add_argument("-q", "--quiet", action="store_true", help="print only errors and the summary")
    return ap


def convert(args, out=None):
    out = sys.stdout if out is None else out   # the stdout of the call, not of the import
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=out))
    card = read_card(args.model_card) if args.model_card else None
    packed = packed_model(args.checkpoint)
    if packed is not None:
        with packed:
            return replace_card(args, packed, card, out)
    inp = read_inputs(args)
    try:
        notes, stderr_notes = [], []
        stated = None
        config_from = args.config  # where the configuration came from, as the notes say it
        if args.config:
            cfg, stated = load_config(args.config)
            how = "from %s" % args.config
            note = dino_sizes_from_tensors(cfg, inp)
            if note:
                stderr_notes.append(note)
        elif matching_preset(_spar_shapes(inp)):
            # The rule spar-reference follows too (model_config.matching_preset): the preset
            # whose sizes the tensors have is the configuration, image size included.
            preset = matching_preset(_spar_shapes(inp))
            cfg = PRESETS[preset]()
            stated = (cfg.image_height, cfg.image_width)
            config_from = "the %s preset" % preset
            how = "the %s preset (the checkpoint's tensor sizes are its)" % preset
            note = dino_sizes_from_tensors(cfg, inp)
            if note:
                stderr_notes.append(note)
        else:
            cfg = infer_config(inp, notes)
            how = "inferred from the tensors"
        # The image size is in no tensor (the codes are sin-cos, DINOv3 uses RoPE): --size,
        # else the configuration's, else the official 256x256, said out loud because a
        # checkpoint trained at another size would otherwise render at 256x256 unnoticed.
        if args.size:
            size_from = "--size"
            if stated and tuple(stated) != tuple(args.size):
                stderr_notes.append("--size %dx%d replaces the %dx%d of %s"
                                    % (args.size + stated + (config_from,)))
            cfg.image_height, cfg.image_width = args.size
        elif stated:
            size_from = "config"
        else:
            size_from = "default"
        size_text = "%dx%d" % (cfg.image_height, cfg.image_width)
        notes.append("image size %s (HxW) from %s" % (size_text, {
            "--size": "--size", "config": config_from,
            "default": "nowhere: the official default"}[size_from]))
        if inp.dino_norm:
            for key in ("mean", "std"):
                if key in inp.dino_norm:
                    ref = inp.dino_norm[key][0]
                    if tuple(ref.shape) != (1, 3, 1, 1) or ref.dtype not in FLOAT_DTYPES:
                        raise ConvertError("tensor %r has shape %s (%s), expected [1, 3, 1, 1]"
                                           % (inp.dino_norm[key][1], list(ref.shape), ref.dtype))
                    cfg.dino[key] = [float("%.7g" % v) for v in ref.numpy().reshape(-1)]
        try:
            cfg.validate()
        except (AssertionError, ValueError) as e:
            raise ConvertError("configuration (%s) is not usable: %s"
                               % (how, _one_line(e) or "validation failed")) from None
        entries, warnings = make_plan(inp, cfg)
        sam2_cfg = sam2_from = None
        if inp.sam2:
            sam2_cfg, sam2_from, sam2_entries = plan_sam2(inp)
            entries += sam2_entries
        converted = {}
        quantized = {}  # name -> {"bits", "block", "shape"}: the `quantized` metadata
        for e in entries:
            if e.dtype == "U8":
                continue
            e.dtype = "F16" if (args.weights == "fp16" and is_matrix(e.name, e.shape)) else "F32"
            if args.weights in ("q8", "q4") and is_quantized(e.name, e.shape):
                e.quant = args.weights
                quantized[e.name] = {"bits": quant.BITS[e.quant], "block": quant.BLOCK, "shape": list(e.shape)}
            stored = e.quant or e.dtype
            if e.kind == "kept":
                comp = e.name.split(".", 1)[0] if e.name.split(".", 1)[0] in ("dino", "lseg", "clip", "sam2") else "spar"
                src = getattr(inp, comp)
                key = e.name[len(PREFIX[comp]):]
                sd = src.tensors[key].dtype
                if {"float32": "F32", "float16": "F16"}.get(sd) != stored:
                    converted[e.name] = "%s -> %s" % (sd, stored)
            elif stored != "F32":
                converted[e.name] = "float64 (folded) -> %s" % stored

        components = {"spar": True, "dino": True, "lseg": bool(cfg.use_lseg),
                      "clip": bool(inp.clip), "bpe": inp.bpe is not None}
        if inp.sam2:  # only then: a file without SAM2 stays byte for byte what it was
            components["sam2"] = True
        record = {
            "converter": PROG,
            "fp16": args.weights == "fp16",
            "components": components,
            "sources": {k: v for k, v in inp.source_of.items()},
            "files": [{"role": r, "path": os.path.basename(p), "bytes": n} for r, p, n in inp.files],
            "config_from": "file" if args.config else ("preset" if config_from else "inferred"),
            "image_size_from": size_from,
            "kept": {e.name: e.sources[0] for e in entries if e.kind == "kept"},
            "folded": {e.name: e.sources for e in entries if e.kind in ("folded", "created")},
            "created": [e.name for e in entries if e.kind == "created"],
            "packed": {e.name: e.sources[0] for e in entries if e.kind == "packed"},
            "dropped": dict(inp.dropped),
            "converted": converted,
            "bn_eps": BN_EPS,
        }
        metadata = {
            "format": FORMAT,
            "format_version": QUANT_FORMAT_VERSION if quantized else FORMAT_VERSION,
            "config": json.dumps(cfg.to_dict(), sort_keys=True, separators=(",", ":")),
            "components": json.dumps(components, sort_keys=True, separators=(",", ":")),
            "conversion": json.dumps(record, sort_keys=True, separators=(",", ":")),
        }
        if quantized:  # only then: a file without quantized matrices stays what it was
            record["weights"] = args.weights
            metadata["quantized"] = json.dumps(quantized, sort_keys=True, separators=(",", ":"))
            metadata["conversion"] = json.dumps(record, sort_keys=True, separators=(",", ":"))
        if card is not None:
            metadata["model_card"] = card_text(card)
        if sam2_cfg is not None:
            metadata["sam2_config"] = json.dumps(sam2_cfg.to_dict(), sort_keys=True, separators=(",", ":"))
            record["sam2_config_from"] = sam2_from
            metadata["conversion"] = json.dumps(record, sort_keys=True, separators=(",", ":"))

        say("%s: configuration %s" % (PROG, how))
        for n in notes:
            say("  " + n)
        say("  config: %s" % json.dumps({k: v for k, v in cfg.to_dict().items()
                                         if k not in ("dino", "lseg", "clip")}, sort_keys=True))
        n_kept = sum(1 for e in entries if e.kind == "kept")
        say("kept %d tensors: %s" % (n_kept, _group([e.name for e in entries if e.kind == "kept"], 2)))
        folded = [e for e in entries if e.kind in ("folded", "created")]
        say("folded %d tensors:" % len(folded))
        for e in folded:
            if "qkv.bias" in e.name:
                say("  %s = qkv.bias * qkv.bias_mask" % e.name)
            elif e.name.endswith(".bias"):
                say("  %s: eval-mode BatchNorm folded into weight and bias%s"
                    % (e.name[:-len(".bias")], " (bias created)" if e.kind == "created" else ""))
        reasons = {}
        for name, reason in inp.dropped.items():
            reasons.setdefault(reason if not reason.startswith("folded into") else
                               "folded (BatchNorm statistics / bias masks)", []).append(name)
        say("dropped %d tensors/entries:" % len(inp.dropped))
        for reason, names in reasons.items():
            say("  %s: %s" % (reason, _group(names)))
        for w in warnings:
            print("%s: warning: unknown tensor dropped: %s" % (PROG, w), file=sys.stderr)
        if converted:
            kinds = {}
            for v in converted.values():
                kinds[v] = kinds.get(v, 0) + 1
            say("converted: %s" % ", ".join("%d x %s" % (n, k) for k, n in sorted(kinds.items())))
        else:
            say("converted: nothing (all F32)")
        if inp.bpe is not None:
            say("packed %s: %d bytes (gzip)" % (BPE_NAME, inp.bpe.size))
        if sam2_cfg is not None:
            n = sum(1 for e in entries if e.name.startswith(sam2_plan.PACKED_PREFIX))
            params = sum(int(np.prod(e.shape)) for e in entries if e.name.startswith(sam2_plan.PACKED_PREFIX))
            say("SAM2 refinement: %s (from %s), %d tensors, %.2f M parameters"
                % (sam2_cfg.name, sam2_from, n, params / 1e6))

        specs = []
        for e in entries:
            specs += _quantized_specs(e) if e.quant else [TensorSpec(e.name, e.dtype, e.shape, _producer(e))]
        write_safetensors(args.output, specs, metadata)
        size_in = sum(n for _, _, n in inp.files)
        size_out = os.path.getsize(args.output)
        print("%s: wrote %s: %d tensors, %s in (%s), %s out%s" % (
            PROG, args.output, len(entries), _fmt_mb(size_in),
            " + ".join("%s %s" % (r, _fmt_mb(n)) for r, _, n in inp.files), _fmt_mb(size_out),
            {"fp16": " (fp16 matrices)", "q8": " (%d q8 matrices)" % len(quantized),
             "q4": " (%d q4 matrices)" % len(quantized)}.get(args.weights, "")), file=out)
        # After the file is complete, so that a refusal stays the one line it is.
        for n in stderr_notes:
            print("%s: note: %s" % (PROG, n), file=sys.stderr)
        if size_from == "default":
            print("%s: warning: the image size is not known (no tensor holds it%s): stored the "
                  "default %s (HxW); give --size HxW if the checkpoint was trained at another "
                  "size" % (PROG, "; %s names none" % args.config if args.config else
                            "; no --config", size_text), file=sys.stderr)
        return 0
    finally:
        inp.close()


def packed_model(path):
    """The open SafetensorsFile of `path` when it is a packed model of this format, else None
    (a checkpoint, a zip archive or a pickle, is no safetensors file; read_inputs says what is
    wrong with a file that is neither)."""
    try:
        f = SafetensorsFile(path)
    except SafetensorsError:
        return None
    if f.metadata.get("format") != FORMAT:
        f.close()
        return None
    return f


def replace_card(args, packed, card, out):
    """A packed model in: every tensor copied byte for byte, the metadata kept, the model card
    replaced by --model-card's (the one change a packed model can take)."""
    others = [o for o, v in (("--config", args.config), ("--size", args.size), ("--fp16", args.fp16),
                             ("--weights", args.weights_given),
                             ("--dino", args.dino), ("--lseg", args.lseg), ("--clip", args.clip),
                             ("--bpe", args.bpe)) if v]
    if others:
        raise ConvertError("%s is a packed model: only --model-card applies to it, not %s"
                           % (args.checkpoint, others[0]))
    if card is None:
        raise ConvertError("%s is a packed model already: give --model-card CARD.json to replace its "
                           "model card" % args.checkpoint)
    if packed.metadata.get("format_version") not in FORMAT_VERSIONS:
        raise ConvertError("%s: format version %r, this converter writes %s"
                           % (args.checkpoint, packed.metadata.get("format_version"), " or ".join(FORMAT_VERSIONS)))
    metadata = dict(packed.metadata, model_card=card_text(card))
    specs = [TensorSpec(n, packed.info(n).dtype, packed.info(n).shape, (lambda n=n: packed.get(n)))
             for n in packed.names]
    write_safetensors(args.output, specs, metadata)
    print("%s: wrote %s: %d tensors copied from %s, model card (%s) replaced"
          % (PROG, args.output, len(specs), args.checkpoint, card["kind"]), file=out)
    return 0


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    args.weights_given = args.weights
    if args.fp16 and args.weights not in (None, "fp16"):
        parser.error("--fp16 is --weights fp16: it cannot go with --weights %s" % args.weights)
    args.weights = "fp16" if args.fp16 else (args.weights or "fp32")
    try:
        return convert(args)
    except (ConvertError, CheckpointError, SafetensorsError, ModelCardError) as e:
        print("%s: error: %s" % (PROG, _one_line(e)), file=sys.stderr)
        return 1
    except OSError as e:
        print("%s: error: %s" % (PROG, _one_line(e)), file=sys.stderr)
        return 1
    except MemoryError:
        print("%s: error: out of memory" % PROG, file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
