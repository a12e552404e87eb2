"""What a SAM2.1 variant is: the sizes of its image encoder (Hiera trunk, FPN neck) and of its
prompt encoder and mask decoder, and the tensors its mask-refinement path reads.

The refinement path is SAM2's single-image path with a mask prompt (SPAR's
``_sam2_refine_masks``): Hiera trunk, FPN neck, ``no_mem_embed``, the prompt encoder's mask
branch and the mask decoder. A variant is named (the four official ``sam2.1_hiera_{t,s,b+,l}``
configs) or read from a YAML file in the official layout (``model.image_encoder.trunk.*`` and
``neck.*``; what a YAML leaves out takes the official Hiera defaults, as the official builder's
class defaults give it). Standard library only (PyYAML for YAML files): the converter and the
reference share it.

Decisions from the official code (facebookresearch/sam2, configs/sam2.1/*.yaml and
modeling/backbones/hieradet.py):
* the background position embedding is 7x7 for t, s and l and 14x14 for b+ (the official
  configs; SPAR's own builder has 14x14 for t and s and cannot load the official files);
* the image size is 1024 (the predictor's feature sizes are fixed to it), so the trunk's maps
  are 256, 128, 64 and 32 tokens a side and the decoder's image embedding is 64x64. An official
  YAML must say 1024; the engine's own JSON form may give a smaller ``image_size`` (a multiple
  of 32): test models, whose refinement then costs (size / 1024)^2 of the official one, while the
  weights stay the same tensors (SAM2Base runs at any such size; only the predictor fixes 1024);
* q-pooling at the first block of stages 2-4, dims and heads x2 there, and the window size of a
  stage's first block is the previous stage's ("lags by a block").
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from typing import Dict, List, Tuple

IMAGE_SIZE = 1024          # SAM2's input side (the predictor's feature sizes assume it)
PATCH_STRIDE = 4           # Hiera's 7x7 stride-4 patch embedding
MASK_INPUT_SIZE = 256      # the mask prompt's side (4 x the 64x64 image embedding)
DECODER_MLP_DIM = 2048     # TwoWayTransformer's MLP width (fixed in SAM2Base._build_sam_heads)
DECODER_HEADS = 8
DECODER_DEPTH = 2
IOU_HEAD_HIDDEN = 256
MASK_IN_CHANS = 16
NUM_MASK_TOKENS = 4        # 3 multimask outputs + the single-mask token

# Hiera's class defaults (hieradet.Hiera.__init__), which a YAML that leaves a field out gets.
HIERA_DEFAULTS = dict(embed_dim=96, num_heads=1, stages=[2, 3, 16, 3], global_att_blocks=[12, 16, 20],
                      window_spec=[8, 4, 14, 7], window_pos_embed_bkg_spatial_size=[14, 14])


class Sam2ConfigError(ValueError):
    """A variant that cannot be built: one line, naming the field."""


@dataclass
class Sam2Config:
    name: str
    embed_dim: int
    num_heads: int
    stages: List[int]
    global_att_blocks: List[int]
    window_spec: List[int]
    window_pos_embed_bkg_spatial_size: List[int]
    d_model: int = 256
    backbone_channel_list: List[int] = field(default_factory=list)
    image_size: int = IMAGE_SIZE

    # ------------------------------------------------------------------ derived sizes
    def token_side(self) -> int:
        """The trunk's first map, tokens a side (256 at 1024)."""
        return self.image_size // PATCH_STRIDE

    def mask_input_size(self) -> int:
        """The mask prompt's and the low-resolution logits' side: 4 x the image embedding's."""
        return self.image_size // PATCH_STRIDE

    def stage_ends(self) -> List[int]:
        return [sum(self.stages[:i + 1]) - 1 for i in range(len(self.stages))]

    def blocks(self) -> List[Dict[str, int]]:
        """Per trunk block: dim, dim_out, heads, window (0 = global), q_pool (0/1), stage."""
        ends = self.stage_ends()
        q_pool = {e + 1 for e in ends[:-1]}
        dim, heads, stage, out = self.embed_dim, self.num_heads, 0, []
        for i in range(sum(self.stages)):
            window = 0 if i in self.global_att_blocks else self.window_spec[stage]
            dim_out = dim
            if i - 1 in ends:
                dim_out, heads, stage = dim * 2, heads * 2, stage + 1
            out.append(dict(dim=dim, dim_out=dim_out, heads=heads, window=window,
                            q_pool=int(i in q_pool), stage=stage))
            dim = dim_out
        return out

    def stage_dims(self) -> List[int]:
        return [self.embed_dim * 2 ** s for s in range(len(self.stages))]

    def validate(self) -> "Sam2Config":
        def ints(name, n=None, positive=True):
            v = getattr(self, name)
            if not isinstance(v, list) or not all(isinstance(x, int) and not isinstance(x, bool) for x in v):
                raise Sam2ConfigError("%s: %r is not a list of integers" % (name, v))
            if n is not None and len(v) != n:
                raise Sam2ConfigError("%s: %d entries, expected %d" % (name, len(v), n))
            if positive and any(x <= 0 for x in v):
                raise Sam2ConfigError("%s: %r has entries below 1" % (name, v))
        for name in ("embed_dim", "num_heads", "d_model", "image_size"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v <= 0:
                raise Sam2ConfigError("%s: %r is not a positive integer" % (name, v))
        ints("stages", 4)
        ints("window_spec", 4)
        ints("window_pos_embed_bkg_spatial_size", 2)
        ints("global_att_blocks", positive=False)
        depth = sum(self.stages)
        bad = [b for b in self.global_att_blocks if not 0 <= b < depth]
        if bad:
            raise Sam2ConfigError("global_att_blocks: block %d is outside the %d blocks" % (bad[0], depth))
        if self.embed_dim % self.num_heads:
            raise Sam2ConfigError("embed_dim %d is not a multiple of num_heads %d"
                                  % (self.embed_dim, self.num_heads))
        want = self.stage_dims()[::-1]
        if self.backbone_channel_list != want:
            raise Sam2ConfigError("neck.backbone_channel_list %r does not match the trunk's stage "
                                  "widths %r (deepest first)" % (self.backbone_channel_list, want))
        if self.d_model % 64:
            raise Sam2ConfigError("neck.d_model %d: the engine needs a multiple of 64 (the decoder's "
                                  "cross-attention has 8 heads of d_model/16, a multiple of 4)" % self.d_model)
        for i, b in enumerate(self.blocks()):
            if (b["dim_out"] // b["heads"]) % 4:
                raise Sam2ConfigError("block %d: heads of %d channels; the engine needs a multiple of 4"
                                      % (i, b["dim_out"] // b["heads"]))
        if self.image_size % 32 or not 64 <= self.image_size <= 2048:
            raise Sam2ConfigError("image_size %d: a multiple of 32 (four stages halving the "
                                  "stride-4 map) in 64..2048" % self.image_size)
        # the window embedding is tiled over the token map (256x256 at 1024)
        side = self.token_side()
        if side % self.window_spec[0]:
            raise Sam2ConfigError("window_spec[0] %d does not divide the %d-token map the window "
                                  "position embedding is tiled over" % (self.window_spec[0], side))
        # a q-pooling block pools inside each window: windows of even size (or global)
        for i, b in enumerate(self.blocks()):
            if b["q_pool"] and b["window"] % 2:
                raise Sam2ConfigError("block %d pools q 2x2 inside windows of %d (odd)" % (i, b["window"]))
        return self

    def to_dict(self) -> Dict:
        return asdict(self)


def _official(name, **trunk) -> Sam2Config:
    t = dict(HIERA_DEFAULTS)
    t.update(trunk)
    dims = [t["embed_dim"] * 2 ** s for s in range(4)]
    return Sam2Config(name=name, d_model=256, backbone_channel_list=dims[::-1], **t)


# The official SAM2.1 configs (configs/sam2.1/sam2.1_hiera_*.yaml).
VARIANTS = {
    "sam2.1_hiera_t": lambda: _official("sam2.1_hiera_t", embed_dim=96, num_heads=1, stages=[1, 2, 7, 2],
                                        global_att_blocks=[5, 7, 9], window_pos_embed_bkg_spatial_size=[7, 7]),
    "sam2.1_hiera_s": lambda: _official("sam2.1_hiera_s", embed_dim=96, num_heads=1, stages=[1, 2, 11, 2],
                                        global_att_blocks=[7, 10, 13], window_pos_embed_bkg_spatial_size=[7, 7]),
    "sam2.1_hiera_b+": lambda: _official("sam2.1_hiera_b+", embed_dim=112, num_heads=2),
    "sam2.1_hiera_l": lambda: _official("sam2.1_hiera_l", embed_dim=144, num_heads=2, stages=[2, 6, 36, 4],
                                        global_att_blocks=[23, 33, 43], window_spec=[8, 4, 16, 8],
                                        window_pos_embed_bkg_spatial_size=[7, 7]),
}
# what users also call them: the checkpoint file names (sam2.1_hiera_large.pt) and short forms
ALIASES = {"sam2.1_hiera_tiny": "sam2.1_hiera_t", "sam2.1_hiera_small": "sam2.1_hiera_s",
           "sam2.1_hiera_base_plus": "sam2.1_hiera_b+", "sam2.1_hiera_large": "sam2.1_hiera_l"}


def variant(name: str) -> Sam2Config:
    key = name if name.startswith("sam2.1_") else "sam2.1_" + name
    if key in ("sam2.1_t", "sam2.1_s", "sam2.1_b+", "sam2.1_l"):  # the short forms
        key = "sam2.1_hiera_" + name
    key = ALIASES.get(key, key)
    if key not in VARIANTS:
        raise Sam2ConfigError("unknown SAM2 variant %r (known: %s, or a YAML file in the official "
                              "layout)" % (name, ", ".join(VARIANTS)))
    return VARIANTS[key]().validate()


def from_yaml_dict(d: Dict, name: str) -> Sam2Config:
    """The official YAML layout: model.image_encoder.{trunk,neck}."""
    try:
        enc = d["model"]["image_encoder"]
        trunk, neck = enc["trunk"], enc["neck"]
    except (KeyError, TypeError):
        raise Sam2ConfigError("%s: no model.image_encoder.trunk / neck (the official SAM2 YAML layout)"
                              % name) from None
    known = set(HIERA_DEFAULTS) | {"_target_"}
    # fields that change the trunk in ways this engine does not build: refused, not ignored
    for k in ("q_pool", "q_stride", "dim_mul", "head_mul", "return_interm_layers"):
        if k in trunk:
            raise Sam2ConfigError("%s: model.image_encoder.trunk.%s is not supported (the official "
                                  "value is the default)" % (name, k))
    t = {k: trunk.get(k, v) for k, v in HIERA_DEFAULTS.items()}
    t = {k: list(v) if isinstance(v, tuple) else v for k, v in t.items()}
    unknown = [k for k in trunk if k not in known and k != "drop_path_rate"]
    if unknown:
        raise Sam2ConfigError("%s: unknown field model.image_encoder.trunk.%s" % (name, unknown[0]))
    if enc.get("scalp", 1) != 1:
        raise Sam2ConfigError("%s: model.image_encoder.scalp %r is not supported (official: 1)"
                              % (name, enc.get("scalp")))
    if neck.get("fpn_top_down_levels", [2, 3]) != [2, 3] or neck.get("fpn_interp_model", "nearest") != "nearest":
        raise Sam2ConfigError("%s: neck.fpn_top_down_levels / fpn_interp_model other than the official "
                              "[2, 3] / nearest are not supported" % name)
    if d["model"].get("image_size", IMAGE_SIZE) != IMAGE_SIZE:
        raise Sam2ConfigError("%s: model.image_size %r: SAM2's image predictor runs at %d only"
                              % (name, d["model"].get("image_size"), IMAGE_SIZE))
    cfg = Sam2Config(name=name, d_model=neck.get("d_model", 256),
                     backbone_channel_list=list(neck.get("backbone_channel_list", [])), **t)
    return cfg.validate()


def read_sam2_config(spec: str) -> Sam2Config:
    """--sam2-config: a variant name, or the path of a YAML (official layout) or of a JSON this
    module wrote (Sam2Config.to_dict())."""
    if os.path.isfile(spec):
        try:
            with open(spec, encoding="utf-8") as f:
                text = f.read()
        except (OSError, UnicodeDecodeError) as e:
            raise Sam2ConfigError("cannot read SAM2 config %s: %s" % (spec, e)) from None
        stem = os.path.splitext(os.path.basename(spec))[0]
        try:
            d = json.loads(text)
            if isinstance(d, dict) and "embed_dim" in d:
                return Sam2Config(**d).validate()
        except json.JSONDecodeError:
            pass
        except TypeError as e:
            raise Sam2ConfigError("SAM2 config %s: %s" % (spec, e)) from None
        try:
            import yaml
            d = yaml.safe_load(text)
        except Exception as e:  # yaml's errors are many classes; one line either way
            raise Sam2ConfigError("SAM2 config %s is not YAML: %s" % (spec, str(e).splitlines()[0])) from None
        return from_yaml_dict(d, stem)
    if spec.endswith((".yaml", ".yml", ".json")):
        raise Sam2ConfigError("SAM2 config file not found: %s" % spec)
    return variant(spec)


def guess_variant(path: str):
    """The official variant a checkpoint's file name says (sam2.1_hiera_large.pt), or None."""
    stem = os.path.splitext(os.path.basename(path))[0]
    for k in list(VARIANTS) + list(ALIASES):
        if stem == k:
            return variant(k)
    return None


# ---------------------------------------------------------------------- tensors of the path
def used_tensors(c: Sam2Config) -> Dict[str, Tuple[int, ...]]:
    """Every tensor the refinement path reads, official key -> shape, in the official order."""
    t: Dict[str, Tuple[int, ...]] = {}
    e, dm = c.embed_dim, c.d_model
    w0 = c.window_spec[0]
    tr = "image_encoder.trunk."
    t[tr + "pos_embed"] = (1, e) + tuple(c.window_pos_embed_bkg_spatial_size)
    t[tr + "pos_embed_window"] = (1, e, w0, w0)
    t[tr + "patch_embed.proj.weight"] = (e, 3, 7, 7)
    t[tr + "patch_embed.proj.bias"] = (e,)
    for i, b in enumerate(c.blocks()):
        p, d, do = tr + "blocks.%d." % i, b["dim"], b["dim_out"]
        t[p + "norm1.weight"] = (d,)
        t[p + "norm1.bias"] = (d,)
        t[p + "attn.qkv.weight"] = (3 * do, d)
        t[p + "attn.qkv.bias"] = (3 * do,)
        t[p + "attn.proj.weight"] = (do, do)
        t[p + "attn.proj.bias"] = (do,)
        t[p + "norm2.weight"] = (do,)
        t[p + "norm2.bias"] = (do,)
        t[p + "mlp.layers.0.weight"] = (4 * do, do)
        t[p + "mlp.layers.0.bias"] = (4 * do,)
        t[p + "mlp.layers.1.weight"] = (do, 4 * do)
        t[p + "mlp.layers.1.bias"] = (do,)
        if d != do:
            t[p + "proj.weight"] = (do, d)
            t[p + "proj.bias"] = (do,)
    for i, cin in enumerate(c.backbone_channel_list):
        t["image_encoder.neck.convs.%d.conv.weight" % i] = (dm, cin, 1, 1)
        t["image_encoder.neck.convs.%d.conv.bias" % i] = (dm,)
    t["no_mem_embed"] = (1, 1, dm)
    pe = "sam_prompt_encoder."
    t[pe + "pe_layer.positional_encoding_gaussian_matrix"] = (2, dm // 2)
    q = MASK_IN_CHANS // 4
    for idx, shape in ((0, (q, 1, 2, 2)), (1, (q,)), (3, (MASK_IN_CHANS, q, 2, 2)), (4, (MASK_IN_CHANS,)),
                       (6, (dm, MASK_IN_CHANS, 1, 1))):
        t[pe + "mask_downscaling.%d.weight" % idx] = shape
        t[pe + "mask_downscaling.%d.bias" % idx] = shape[:1]
    md = "sam_mask_decoder."
    for layer in range(DECODER_DEPTH):
        p = md + "transformer.layers.%d." % layer
        # TwoWayAttentionBlock's order: self_attn, norm1, cross t2i, norm2, mlp, norm3, norm4, cross i2t
        _attention(t, p + "self_attn.", dm, dm)
        _norm(t, p + "norm1.", dm)
        _attention(t, p + "cross_attn_token_to_image.", dm, dm // 2)
        _norm(t, p + "norm2.", dm)
        t[p + "mlp.layers.0.weight"] = (DECODER_MLP_DIM, dm)
        t[p + "mlp.layers.0.bias"] = (DECODER_MLP_DIM,)
        t[p + "mlp.layers.1.weight"] = (dm, DECODER_MLP_DIM)
        t[p + "mlp.layers.1.bias"] = (dm,)
        _norm(t, p + "norm3.", dm)
        _norm(t, p + "norm4.", dm)
        _attention(t, p + "cross_attn_image_to_token.", dm, dm // 2)
    _attention(t, md + "transformer.final_attn_token_to_image.", dm, dm // 2)
    t[md + "transformer.norm_final_attn.weight"] = (dm,)
    t[md + "transformer.norm_final_attn.bias"] = (dm,)
    t[md + "iou_token.weight"] = (1, dm)
    t[md + "mask_tokens.weight"] = (NUM_MASK_TOKENS, dm)
    t[md + "obj_score_token.weight"] = (1, dm)
    t[md + "output_upscaling.0.weight"] = (dm, dm // 4, 2, 2)
    t[md + "output_upscaling.0.bias"] = (dm // 4,)
    t[md + "output_upscaling.1.weight"] = (dm // 4,)
    t[md + "output_upscaling.1.bias"] = (dm // 4,)
    t[md + "output_upscaling.3.weight"] = (dm // 4, dm // 8, 2, 2)
    t[md + "output_upscaling.3.bias"] = (dm // 8,)
    t[md + "conv_s0.weight"] = (dm // 8, dm, 1, 1)
    t[md + "conv_s0.bias"] = (dm // 8,)
    t[md + "conv_s1.weight"] = (dm // 4, dm, 1, 1)
    t[md + "conv_s1.bias"] = (dm // 4,)
    for m in range(1, NUM_MASK_TOKENS):  # hypernetwork 0 (the single-mask token's) is never read
        _mlp(t, md + "output_hypernetworks_mlps.%d.layers." % m, dm, dm, dm // 8)
    _mlp(t, md + "iou_prediction_head.layers.", dm, IOU_HEAD_HIDDEN, NUM_MASK_TOKENS)
    return t


def _attention(t, p, dm, internal):
    for n in ("q_proj", "k_proj", "v_proj"):
        t[p + n + ".weight"] = (internal, dm)
        t[p + n + ".bias"] = (internal,)
    t[p + "out_proj.weight"] = (dm, internal)
    t[p + "out_proj.bias"] = (dm,)


def _norm(t, p, d):
    t[p + "weight"] = (d,)
    t[p + "bias"] = (d,)


def _mlp(t, p, din, hidden, dout):
    for i, (a, b) in enumerate(((hidden, din), (hidden, hidden), (dout, hidden))):
        t[p + "%d.weight" % i] = (a, b)
        t[p + "%d.bias" % i] = (a,)


def discarded_tensors(c: Sam2Config) -> Dict[str, Tuple[int, ...]]:
    """Computed by the official path but never part of its result (the object-score head,
    hypernetwork 0): a checkpoint has them, the packed file does not."""
    t: Dict[str, Tuple[int, ...]] = {}
    md, dm = "sam_mask_decoder.", c.d_model
    _mlp(t, md + "pred_obj_score_head.layers.", dm, dm, 1)
    _mlp(t, md + "output_hypernetworks_mlps.0.layers.", dm, dm, dm // 8)
    return t


# Prefixes of the tensors of SAM2's video path (memory, object pointers) and of the point and
# box prompts: in every official checkpoint, never on the refinement path.
UNUSED_PREFIXES = ("memory_attention.", "memory_encoder.", "maskmem_tpos_enc", "no_mem_pos_enc",
                   "no_obj_ptr", "no_obj_embed_spatial", "mask_downsample.", "obj_ptr_proj.",
                   "obj_ptr_tpos_proj.", "sam_prompt_encoder.point_embeddings.",
                   "sam_prompt_encoder.not_a_point_embed.", "sam_prompt_encoder.no_mask_embed.")


def is_unused(key: str) -> bool:
    return key.startswith(UNUSED_PREFIXES)
