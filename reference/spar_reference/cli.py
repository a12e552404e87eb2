#!/usr/bin/python3
"""``spar-reference``: command-line tool of the PyTorch reference.

Subcommands:
  make-checkpoint  a checkpoint as the official training saves it (spar.make_checkpoint)
  render           the reference's own run: rendered views, motion masks, cameras, labels
  goldens          prepared inputs and every stage's output as .npy files with a manifest
  batch            the command lines of a JSON file, one after another in one process

Views are ONE ordered sequence: ``--images A B --targets C D`` is the sequence A B C D with
inputs A B; ``--frames f0 f1 f2 f3 f4 --inputs 0,3,4`` has inputs 0, 3, 4 and targets 1, 2.
The pose encoder sees the whole sequence; the canonical view is its middle (V//2).
Image preparation: ``images.py``; camera conventions: ``cameras.py``; golden files:
``goldens.py``.

  spar-reference make-checkpoint --config tiny|full|PATH -o X.pt [--seed N] [--perturb]
                                 [--no-optimizer] [--threads N]
  spar-reference render --checkpoint X.pt [--config tiny|full|PATH]
        (--images A B ... [--targets C D ...] | --frames f0 f1 ... --inputs 0,3,4)
        [--cameras transforms.json | --path N] [--labels "a,b"] [--features] [--bpe PATH]
        [--float64] [--threads N] --out DIR
  spar-reference goldens  (same view / camera / label options, no --features) --out DIR
  spar-reference batch RUNS.json   (a JSON list of argument lists: [["render", ...], ...])

render writes view_XX.png (rendered views: the targets, or the --path / --cameras cameras),
motion_XX.png / mask_XX.png (input views: P(dynamic) as 8-bit grey, mask P > 0.5 as 0/255,
at the model's H x W), cameras.json (every view's estimated camera in the nerfstudio
convention that --cameras reads, plus "order", "inputs", "targets", "canonical_index" and
"render_frames" for --path / --cameras), report.json (device, precision, total_seconds,
stages that ran with their seconds), path.gif for a --path of 2 or more views (each view
beside its label map when --labels is given, 8 frames a second); with --labels labels_XX.png / .json per rendered view
(argmax of 1/0.07 * <normalized semantic features, normalized CLIP text embeddings> at H/2 x
W/2; prompts are comma-separated, so a prompt cannot contain a comma); with --features
features_XX.npy (C x H/2 x W/2 float32). Without --labels / --features the semantic head and
the text encoder do not run (the semantic queries still take part in the decoder, as in the
official evaluation, so RGB does not depend on these options).
The config comes from --config, else from the checkpoint's tensor sizes: a matching preset
(tiny, full), else the converter's inference (image size then 256 x 256, the official default).
CLIP text weights are read from lseg_model.clip_pretrained.* (where the official LSegNet holds
its CLIP); make-checkpoint writes them there. Errors: one line ``spar-reference: error: ...`` on stderr, exit code 1, and
no output directory (outputs are written into DIR.tmp-XXXX and renamed at the end).
"""

import argparse
import json
import math
import os
import shutil
import sys
import tempfile
import time
from collections import OrderedDict
from contextlib import contextmanager
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

PROG = "spar-reference"
# The repository's copy of CLIP's merges table (text/data/clip/, MIT licence beside it).
DEFAULT_BPE = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..",
                                            "text", "data", "clip", "bpe_simple_vocab_16e6.txt.gz"))
CLIP_PREFIX = "lseg_model.clip_pretrained."   # official: LSegNet.clip_pretrained inside lseg_model
CLIP_TEXT_ROOTS = ("token_embedding.", "positional_embedding", "transformer.", "ln_final.",
                   "text_projection")
IGNORED_PREFIXES = ("spar_loss_computer.",)    # training-only (VGG19 of the perceptual loss)


class CliError(Exception):
    """A user-facing error: printed as one line, exit code 1."""


# ============================================================================ helpers
def default_bpe() -> str:
    return os.environ.get("SPAR_CLIP_BPE") or DEFAULT_BPE


class StageTimer:
    """Wall time per stage, in the order stages first ran; module hooks add the model's."""

    def __init__(self):
        self.times: "OrderedDict[str, float]" = OrderedDict()
        self._start: Dict[int, float] = {}
        self._handles = []

    def add(self, name: str, dt: float) -> None:
        self.times[name] = self.times.get(name, 0.0) + dt

    @contextmanager
    def __call__(self, name: str):
        t = time.perf_counter()
        try:
            yield
        finally:
            self.add(name, time.perf_counter() - t)

    def hook(self, module, name: str) -> None:
        if module is None:
            return

        def pre(m, inp):
            self._start[id(m)] = time.perf_counter()

        def post(m, inp, out):
            self.add(name, time.perf_counter() - self._start.pop(id(m)))
        self._handles.append(module.register_forward_pre_hook(pre))
        self._handles.append(module.register_forward_hook(post))

    def hooked_total(self, names: Sequence[str]) -> float:
        return sum(self.times.get(n, 0.0) for n in names)

    def remove_hooks(self) -> None:
        for h in self._handles:
            h.remove()
        self._handles = []


MODEL_STAGES = [
    # (stage, attributes of SPAR timed by hooks; ModuleLists: each block)
    ("image_tokens", ("image_tokenizer", "pe_embedder")),
    ("pose_encoder", ("temporal_pe_embedder", "transformer_encoder")),
    ("pose_head", ("pose_predictor",)),
    ("ray_tokens", ("target_pose_tokenizer",)),
    ("dino", ("_dino_v3",)),
    ("cv_drp", ("cv_drp",)),
    ("token_fusion", ("mlp_fuse",)),
    ("lseg", ("lseg_model",)),
    ("semantic_tokens", ("semantic_pool", "semantic_proj")),
    ("scene_encoder", ("transformer_encoder_geom",)),
    ("decoder", ("target_pose_tokenizer2", "target_pose_tokenizer_semantic", "decoder_ln",
                 "transformer_decoder")),
    ("rgb_head", ("image_token_decoder",)),
    ("semantic_head", ("semantic_token_decoder", "semantic_feature_expansion")),
]


# The engine's stages (model/spar_pipeline.cpp, report.json / spar-bench) -> the reference's
# stages above that cover the same work (scripts/compare/compare_full.py, scripts/gpu/gpu_check_report.py).
ENGINE_STAGE_MAP = [
    ("image_tokens", ["image_tokens"]),
    ("pose_estimator", ["pose_encoder", "pose_head"]),
    ("rays", ["ray_tokens"]),
    ("dino_v3", ["dino"]),
    ("cv_drp", ["cv_drp"]),
    ("gating", ["token_fusion"]),
    ("lseg", ["lseg"]),
    ("semantic_tokens", ["semantic_tokens"]),
    ("scene_encoder", ["scene_encoder"]),
    ("renderer", ["decoder", "rgb_head", "semantic_head"]),
]


def attach_stage_hooks(timer: StageTimer, model) -> List[str]:
    import torch.nn as nn
    names = []
    for stage, attrs in MODEL_STAGES:
        names.append(stage)
        for a in attrs:
            mod = getattr(model, a, None)
            if isinstance(mod, nn.ModuleList):
                for blk in mod:
                    timer.hook(blk, stage)
            elif isinstance(mod, nn.Module):
                timer.hook(mod, stage)
    return names


# ============================================================================ checkpoint
def load_checkpoint(path: str, what: str = "SPAR") -> Dict[str, Any]:
    """The model state_dict of a checkpoint file ({"model": ...} or a bare state_dict); a SPAR
    checkpoint (what="SPAR") must hold scene_code."""
    import torch
    if not os.path.isfile(path):
        raise CliError(f"checkpoint not found: {path}")
    # The converter's restricted reader: runs no code stored in the file (torch 1.13's
    # weights_only unpickler cannot read an optimizer state).
    from spar_convert.torch_checkpoint import CheckpointError, open_checkpoint
    try:
        with open_checkpoint(path) as ck:
            sd = OrderedDict((k, torch.from_numpy(np.array(v.numpy(), copy=True)))
                             for k, v in ck.state_dict.items())
    except CheckpointError as e:
        raise CliError(f"cannot read checkpoint: {_one_line(e)}")
    except Exception as e:
        raise CliError(f"cannot read checkpoint {path}: {_one_line(e)}")
    if not isinstance(sd, dict) or not sd or not all(isinstance(v, torch.Tensor) for v in sd.values()):
        raise CliError(f"not a {what} checkpoint (no state_dict of tensors): {path}")
    if what == "SPAR" and "scene_code" not in sd:
        raise CliError(f"not a SPAR checkpoint (no scene_code tensor): {path}")
    return sd


def infer_config(sd: Dict[str, Any], path: str):
    """The config of a checkpoint, by the rule spar-convert follows too
    (spar_convert.model_config.matching_preset): the preset (tiny, full) whose tensor sizes the
    checkpoint matches (image size and the other sizes the tensors do not carry come from the
    preset); else the converter's inference from the tensors (spar_convert.convert.infer_config:
    the sizes the tensors do not carry, image size included, are the official defaults)."""
    from . import config as config_mod
    from spar_convert.model_config import matching_preset
    preset = matching_preset({k: tuple(v.shape) for k, v in sd.items()})
    if preset:
        return config_mod.PRESETS[preset]()
    from types import SimpleNamespace
    from spar_convert.convert import infer_config as convert_infer, read_inputs
    try:
        inp = read_inputs(SimpleNamespace(checkpoint=path, dino=None, lseg=None, clip=None,
                                          bpe=None))
        try:
            return convert_infer(inp, []).validate()
        finally:
            inp.close()
    except Exception as e:
        raise CliError(f"cannot infer the model configuration from the checkpoint "
                       f"({_one_line(e)}); pass --config tiny|full|PATH")


def get_config(arg: Optional[str], sd: Optional[Dict[str, Any]], path: str = ""):
    from . import config as config_mod
    if arg:
        if arg not in config_mod.PRESETS and not os.path.isfile(arg):
            raise CliError(f"config not found: {arg} (a preset: {', '.join(config_mod.PRESETS)}, "
                           "or a YAML/JSON file)")
        try:
            return config_mod.get_config(arg)
        except Exception as e:
            raise CliError(f"bad config {arg}: {_one_line(e)}")
    if sd is None:
        raise CliError("--config is required")
    return infer_config(sd, path)


def split_state_dict(sd: Dict[str, Any]) -> Tuple[Dict[str, Any], Dict[str, Any]]:
    """(SPAR's tensors incl. the backbones, CLIP text tensors without prefix). The CLIP visual
    tower and logit_scale under lseg_model.clip_pretrained and training-only tensors are
    dropped (no inference path uses them)."""
    model, clip = {}, {}
    for k, v in sd.items():
        if k.startswith(CLIP_PREFIX):
            sub = k[len(CLIP_PREFIX):]
            if sub.startswith(CLIP_TEXT_ROOTS):
                clip[sub] = v
        elif not k.startswith(IGNORED_PREFIXES):
            model[k] = v
    return model, clip


def build_model(cfg, sd: Dict[str, Any], float64: bool):
    """SPAR (with its DINOv3 / LSeg references) holding exactly the checkpoint's tensors."""
    import torch
    from .spar import SPAR
    if cfg.use_lseg and not any(k.startswith("lseg_model.") for k in sd):
        raise CliError("checkpoint has no LSeg weights (lseg_model.*) but the config uses LSeg")
    if not any(k.startswith("_dino_v3.") for k in sd):
        raise CliError("checkpoint has no DINOv3 weights (_dino_v3.*): this tool needs a "
                       "training checkpoint that carries them")
    # cheap size check first: building a full-size model takes a while
    from spar_convert.model_config import checkpoint_signature, tensor_signature
    want = tensor_signature(cfg)
    got = checkpoint_signature({k: tuple(v.shape) for k, v in sd.items()}, want)
    diff = [k for k in want if want[k] != got[k]]
    if diff:
        k = diff[0]
        what = (f"{k[2:]}: {got[k]} layers in the checkpoint, {want[k]} in the config"
                if k.startswith("n:") else
                f"{k}: checkpoint {list(got[k]) if got[k] else 'absent'}, config "
                f"{list(want[k]) if want[k] else 'absent'}")
        raise CliError(f"checkpoint does not match the model config ({what})")
    try:
        # No initial values anywhere (every tensor comes from the checkpoint, checked below):
        # backbones built on the meta device, then given uninitialized CPU storage of the dtype
        # they run at; SPAR's own modules built in that dtype without torch.nn.init. Loading
        # the checkpoint is then the one pass over the weights (converting as it copies).
        from .backbones import no_initial_values
        from .dino_v3 import DinoV3
        dtype = torch.float64 if float64 else torch.float32
        dino = DinoV3(cfg.dino, device="meta").to(dtype).to_empty(device="cpu")
        lseg = False
        if cfg.use_lseg:
            from .lseg import LSegEncoder
            lseg = LSegEncoder(cfg.lseg, device="meta").to(dtype).to_empty(device="cpu")
        with no_initial_values(dtype):
            model = SPAR(cfg, dino=dino, lseg=lseg)
        model = model.to(dtype)
    except Exception as e:
        raise CliError(f"cannot build the model for this config: {_one_line(e)}")
    own = model.state_dict()
    missing = [k for k in own if k not in sd]
    unexpected = [k for k in sd if k not in own]
    shape = [k for k in own if k in sd and tuple(own[k].shape) != tuple(sd[k].shape)]
    if missing or unexpected or shape:
        parts = []
        if missing:
            parts.append(f"{len(missing)} missing (e.g. {missing[0]})")
        if unexpected:
            parts.append(f"{len(unexpected)} unexpected (e.g. {unexpected[0]})")
        if shape:
            k = shape[0]
            parts.append(f"{len(shape)} of another shape (e.g. {k}: checkpoint "
                         f"{list(sd[k].shape)}, config {list(own[k].shape)})")
        raise CliError("checkpoint does not match the model config: " + "; ".join(parts))
    model.load_state_dict(sd, strict=True)
    return model.eval()


def build_text_encoder(cfg, clip_sd: Dict[str, Any], float64: bool):
    from .clip_text import CLIPTextEncoder
    need = ("token_embedding.weight", "positional_embedding", "ln_final.weight", "text_projection")
    if not clip_sd or any(k not in clip_sd for k in need):
        raise CliError(f"checkpoint has no CLIP text weights ({CLIP_PREFIX}token_embedding..., "
                       "text_projection): --labels needs them")
    c = dict(cfg.clip)
    c["vocab_size"], c["width"] = (int(x) for x in clip_sd["token_embedding.weight"].shape)
    c["context_length"] = int(clip_sd["positional_embedding"].shape[0])
    c["embed_dim"] = int(clip_sd["text_projection"].shape[1])
    c["layers"] = len({k.split(".")[2] for k in clip_sd if k.startswith("transformer.resblocks.")})
    if c["width"] % int(c.get("heads", 8)):
        raise CliError("CLIP text width is not a multiple of the configured heads")
    if c["embed_dim"] != cfg.semantic_dim:
        raise CliError(f"CLIP text embedding width {c['embed_dim']} differs from the semantic "
                       f"feature width {cfg.semantic_dim}")
    enc = CLIPTextEncoder(c)
    try:
        enc.load_state_dict(clip_sd, strict=True)
    except RuntimeError as e:
        raise CliError(f"CLIP text weights do not match: {_one_line(e)}")
    enc = enc.double() if float64 else enc.float()
    return enc.eval()


def add_clip_text(ck: Dict[str, Any], cfg, seed: int, perturb: bool, encoder=None) -> None:
    """Put CLIP text weights into the checkpoint where the official SPAR has them: its
    ``lseg_model`` is lang-seg's LSegNet, which holds a whole CLIP as ``clip_pretrained``.
    Only the text tower and logit_scale are written (the visual tower is never used).
    ``encoder``: a CLIPTextEncoder to write (else one is made from ``seed``)."""
    import torch
    from .clip_text import CLIPTextEncoder
    enc = encoder if encoder is not None else CLIPTextEncoder(cfg.clip, seed=seed, perturb=perturb)
    enc = enc.float()
    extra = OrderedDict((CLIP_PREFIX + k, v.detach().clone()) for k, v in enc.state_dict().items())
    extra[CLIP_PREFIX + "logit_scale"] = torch.tensor(math.log(1.0 / 0.07), dtype=torch.float32)
    sd = ck["model"]
    keys = list(sd)
    last = max((i for i, k in enumerate(keys) if k.startswith("lseg_model.")), default=len(keys) - 1)
    new = OrderedDict()
    for i, k in enumerate(keys):
        new[k] = sd[k]
        if i == last:
            new.update(extra)
    ck["model"] = new


# ============================================================================ views
def _one_line(e: BaseException) -> str:
    s = str(e).strip().replace("\n", " ")
    return s if s else e.__class__.__name__


def plan_views(args) -> Tuple[List[str], List[int], List[int]]:
    """(files in sequence order, input indices, target indices)."""
    if args.images:
        files = list(args.images) + list(args.targets or [])
        inputs = list(range(len(args.images)))
        targets = list(range(len(args.images), len(files)))
    else:
        if args.targets:
            raise CliError("--targets goes with --images; with --frames the frames not in "
                           "--inputs are the targets")
        if not args.inputs:
            raise CliError("--frames needs --inputs (e.g. --inputs 0,3,4)")
        files = list(args.frames)
        try:
            inputs = [int(x) for x in args.inputs.replace(" ", "").split(",") if x != ""]
        except ValueError:
            raise CliError(f"--inputs must be comma-separated frame positions, got {args.inputs!r}")
        if len(set(inputs)) != len(inputs):
            raise CliError(f"--inputs repeats a position: {args.inputs}")
        bad = [i for i in inputs if not 0 <= i < len(files)]
        if bad:
            raise CliError(f"--inputs position {bad[0]} is outside the {len(files)} frames")
        inputs = sorted(inputs)
        targets = [i for i in range(len(files)) if i not in inputs]
    if args.targets is not None and args.images and not args.targets:
        raise CliError("--targets needs at least one image")
    if len(inputs) < 2:
        raise CliError(f"need at least 2 input views, got {len(inputs)}")
    from PIL import Image
    for f in files:
        if not os.path.isfile(f):
            raise CliError(f"image not found: {f}")
        try:  # identify the format now, before the checkpoint is loaded
            with Image.open(f) as im:
                im.size
        except Exception as e:
            raise CliError(f"cannot read image {f}: {e.__class__.__name__}: {_one_line(e)}")
    return files, inputs, targets


def parse_labels(text: Optional[str]) -> Optional[List[str]]:
    if text is None:
        return None
    labels = [x.strip() for x in text.split(",") if x.strip()]
    if not labels:
        raise CliError("--labels needs at least one prompt")
    if len(set(labels)) != len(labels):
        raise CliError("--labels repeats a prompt")
    return labels


def check_out_dir(path: str) -> str:
    path = os.path.abspath(path)
    if os.path.lexists(path):
        raise CliError(f"output directory already exists: {path}")
    parent = os.path.dirname(path)
    if not os.path.isdir(parent):
        raise CliError(f"parent directory does not exist: {parent}")
    return path


@contextmanager
def staged_dir(path: str):
    """A fresh DIR.tmp-XXXX next to ``path``, renamed to ``path`` when the block succeeds and
    removed when it fails."""
    tmp = tempfile.mkdtemp(prefix=os.path.basename(path) + ".tmp-", dir=os.path.dirname(path))
    try:
        yield tmp
        os.rename(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


# ============================================================================ the run
class Run:
    """One reference run shared by ``render`` and ``goldens``."""

    def __init__(self, args, goldens: bool):
        import torch
        self.args = args
        self.goldens = goldens
        self.timer = StageTimer()
        self.t0 = time.perf_counter()
        self.float64 = bool(args.float64)
        self.dtype = torch.float64 if self.float64 else torch.float32
        self.files, self.inputs, self.targets = plan_views(args)
        self.labels = parse_labels(args.labels)
        self.want_features = bool(getattr(args, "features", False))
        self.assume_static = bool(args.assume_static)
        self.bpe = args.bpe or default_bpe()
        if self.labels and not os.path.isfile(self.bpe):
            raise CliError(f"CLIP merges table not found: {self.bpe} (give --bpe PATH)")
        if args.config:
            from .config import PRESETS
            if args.config not in PRESETS and not os.path.isfile(args.config):
                raise CliError(f"config not found: {args.config} (a preset: "
                               f"{', '.join(PRESETS)}, or a YAML/JSON file)")
        if args.cameras and not os.path.isfile(args.cameras):
            raise CliError(f"cameras file not found: {args.cameras}")
        if args.path is not None and args.path < 1:
            raise CliError("--path needs at least 1 frame")
        if (self.labels or self.want_features) and not self.targets and args.path is None \
                and not args.cameras:
            raise CliError("--labels / --features need views to render (target views, --path "
                           "or --cameras)")
        self.mask_source = getattr(args, "mask_source", "raw")
        self.refine = bool(getattr(args, "refine", False)) or self.mask_source == "refined"
        if self.refine and self.assume_static:
            raise CliError("--refine / --mask-source refined need CV-DRP's masks: not with --assume-static")
        if self.refine and not args.sam2:
            raise CliError("--refine / --mask-source refined need --sam2 SAM2.pt")
        if args.sam2 and not os.path.isfile(args.sam2):
            raise CliError(f"SAM2 checkpoint not found: {args.sam2}")
        self.out_path = check_out_dir(args.out)

    def load_sam2(self):
        """The SAM2.1 weights of the refinement path and their variant (spar_convert's rules)."""
        from spar_convert.sam2_plan import Sam2PlanError, resolve
        from .sam2 import as_dtype
        sd = load_checkpoint(self.args.sam2, "SAM2.1")
        try:
            cfg, _ = resolve({k: tuple(v.shape) for k, v in sd.items()}, self.args.sam2, self.args.sam2_config)
            return as_dtype(sd, cfg, self.dtype), cfg
        except (Sam2PlanError, KeyError, ValueError) as e:
            raise CliError(f"{self.args.sam2}: {_one_line(e)}")

    def refine_masks(self, out) -> Dict[str, Any]:
        """SAM2.1's refinement of CV-DRP's masks (inputs, then targets): refined_input /
        refined_target [1, V, 1, H, W] 0/1, and per refined view the IoU predictions and the
        chosen mask's 256x256 logits (refine_iou [N, 3], refine_logits [N, 256, 256]; skipped
        views have none)."""
        import torch
        from .sam2 import refine_masks
        sd, cfg = self.sam2
        images = torch.from_numpy(self.images).to(self.dtype)
        result, ious, logits = {}, [], []
        with self.timer("sam2_refine"):
            for which, idx in (("input", self.inputs), ("target", self.targets)):
                motion = out.get("cv_drp_" + which)
                if not motion or not idx:
                    continue
                views = refine_masks(sd, cfg, images[list(idx)], motion["prob"][0, :, 0].to(self.dtype), self.dtype)
                result["refined_" + which] = torch.stack([r["refined"] for r in views])[None, :, None]
                for r in views:
                    if not r["skipped"]:
                        ious.append(r["iou"])
                        logits.append(r["logits"])
                result["refine_skipped_" + which] = torch.tensor([r["skipped"] for r in views])
        if ious:
            result["refine_iou"] = torch.stack(ious)
            result["refine_logits"] = torch.stack(logits)
        return result

    # ---------------------------------------------------------------- compute
    def compute(self, state_dict: Optional[Dict[str, Any]] = None) -> None:
        """The run. ``state_dict``: the tensors of --checkpoint when the caller holds them
        already (an in-process caller that has just saved them there), else read from it."""
        import torch
        from .images import load_image
        args, timer = self.args, self.timer
        with timer("load_checkpoint"):
            sd = load_checkpoint(args.checkpoint) if state_dict is None else state_dict
            cfg = get_config(args.config, sd, args.checkpoint)
            model_sd, clip_sd = split_state_dict(sd)
            self.cfg = cfg
            self.model = build_model(cfg, model_sd, self.float64)
            if (self.labels or self.want_features) and not cfg.semantic_decoding:
                raise CliError("this model has no semantic decoding (use_lseg / semantic loss "
                               "weight): --labels / --features are not available")
            self.text_encoder = None
            if self.labels:
                self.text_encoder = build_text_encoder(cfg, clip_sd, self.float64)
        if self.refine:  # before any work: a SAM2 file that does not fit is refused first
            with timer("load_sam2"):
                self.sam2 = self.load_sam2()
        h, w = cfg.image_height, cfg.image_width
        with timer("prepare_images"):
            npdt = np.float64 if self.float64 else np.float32
            from .images import ImageError
            try:
                imgs = np.stack([load_image(f, h, w, npdt) for f in self.files])
            except ImageError as e:
                raise CliError(str(e))
            self.images = imgs
            render_cams = None
            if args.cameras:
                from .cameras import read_transforms, CameraError
                try:
                    render_cams = read_transforms(args.cameras, w, h)
                except CameraError as e:
                    raise CliError(str(e))

        model = self.model
        hooked = attach_stage_hooks(timer, model)
        x = torch.from_numpy(imgs)[None].to(self.dtype)
        t = time.perf_counter()
        try:
            with torch.no_grad():
                out = model(x, self.inputs, self.targets, render=False,
                            record_layers=self.goldens, assume_static=self.assume_static)
                if self.refine:
                    refined = self.refine_masks(out)
                    if self.mask_source == "refined":
                        # the official mask_source 'refined': the hard masks gate, average-pooled
                        out = model(x, self.inputs, self.targets, render=False, record_layers=self.goldens,
                                    dynamic_mask=refined["refined_input"])
                    out.update(refined)
                if args.path is not None:
                    from .cameras import interpolate_path
                    c2w = out["c2w"][0].double().numpy()
                    k = out["fxfycxcy"][0].double().numpy()
                    path = interpolate_path(c2w[self.inputs], args.path)
                    render_cams = (path, np.repeat(k[self.inputs[:1]], args.path, axis=0))
                r_c2w = r_k = None
                if render_cams is not None:
                    r_c2w = torch.from_numpy(render_cams[0])[None].to(self.dtype)
                    r_k = torch.from_numpy(render_cams[1])[None].to(self.dtype)
                rec = out["layers"]["transformer_decoder"] if self.goldens else None
                model.render(out, r_c2w, r_k, record=rec,
                             semantic_head=self.goldens or self.labels is not None
                             or self.want_features)
        finally:
            timer.remove_hooks()
        glue = time.perf_counter() - t - timer.hooked_total(hooked)
        timer.add("forward_glue", max(0.0, glue))
        self.out = out
        self.render_mode = "cameras" if args.cameras else ("path" if args.path is not None
                                                           else "targets")
        if self.labels:
            self.compute_labels()

    def compute_labels(self) -> None:
        import torch
        from .bpe import tokenize
        from .clip_text import full_resolution_labels, label_logits
        with self.timer("text_encoder"):
            try:
                ids = tokenize(self.labels, self.bpe, self.text_encoder.context_length)
            except Exception as e:
                raise CliError(f"cannot tokenize the labels with {self.bpe}: {_one_line(e)}")
            with torch.no_grad():
                txt = self.text_encoder(ids)
        with self.timer("labels"):
            feat = self.out["semantic_features"][0]               # [R, C, H/2, W/2]
            logits = label_logits(feat, txt)                      # [R, P, H/2, W/2]
            maps = full_resolution_labels(logits)                 # [R, H, W], the official order
        self.text_ids, self.text_emb, self.label_logits, self.label_maps = ids, txt, logits, maps

    # ---------------------------------------------------------------- outputs
    def order(self) -> List[Dict[str, Any]]:
        return [{"index": i, "file": os.path.abspath(f),
                 "role": "input" if i in self.inputs else "target"}
                for i, f in enumerate(self.files)]

    def cameras_json(self) -> Dict[str, Any]:
        from .cameras import camera_entry
        cfg = self.cfg
        w, h = cfg.image_width, cfg.image_height
        c2w = self.out["c2w"][0].double().numpy()
        k = self.out["fxfycxcy"][0].double().numpy()
        order = self.order()
        frames = [camera_entry(c2w[i], k[i], w, h, file_path=o["file"], index=i, role=o["role"])
                  for i, o in enumerate(order)]
        ci = self.model.pose_predictor.canonical_index(len(self.files))
        doc = {
            "camera_model": "PINHOLE",
            "convention": ("nerfstudio: transform_matrix is camera-to-world in OpenGL axes "
                           "(x right, y up, z back); c2w_opencv = transform_matrix @ "
                           "diag(1,-1,-1,1) is SPAR's (x right, y down, z forward); world = "
                           "the canonical view's camera; intrinsics in pixels of the model's "
                           "w x h image, intrinsics_normalized = (fx/w, fy/h, cx/w, cy/h)"),
            "w": w, "h": h,
            "fl_x": frames[0]["fl_x"], "fl_y": frames[0]["fl_y"],
            "cx": frames[0]["cx"], "cy": frames[0]["cy"],
            "canonical_index": ci,
            "order": order,
            "inputs": list(self.inputs), "targets": list(self.targets),
            "frames": frames,
        }
        if self.render_mode != "targets":
            rc = self.out["render_c2w"][0].double().numpy()
            rk = self.out["render_fxfycxcy"][0].double().numpy()
            doc["render"] = self.render_mode
            doc["render_frames"] = [camera_entry(rc[j], rk[j], w, h, index=j, role="render")
                                    for j in range(rc.shape[0])]
        else:
            doc["render"] = "targets"
        return doc

    def report(self) -> Dict[str, Any]:
        import torch
        total = time.perf_counter() - self.t0
        return {
            "tool": PROG, "command": "goldens" if self.goldens else "render",
            "device": "pytorch-cpu", "precision": "fp64" if self.float64 else "fp32",
            "torch": torch.__version__, "threads": torch.get_num_threads(),
            "views": {"total": len(self.files), "inputs": len(self.inputs),
                      "targets": len(self.targets),
                      "rendered": int(self.out["rgb"].shape[1]) if "rgb" in self.out else 0},
            "render": self.render_mode,
            "assume_static": self.assume_static,
            "refine": {"mask_source": self.mask_source} if self.refine else None,
            "total_seconds": total,
            "stages": [{"name": k, "seconds": v} for k, v in self.timer.times.items()],
        }

    def write_render(self, d: str) -> None:
        from .images import save_grey, save_label_map, save_mask, save_rgb, palette_colour
        cfg = self.cfg
        out = self.out
        with self.timer("write_outputs"):
            rgb = out["rgb"][0].double().numpy() if "rgb" in out else np.zeros((0,))
            for j in range(rgb.shape[0]):
                save_rgb(os.path.join(d, f"view_{j:02d}.png"), rgb[j])
            motion = out["cv_drp_input"]  # None for --assume-static: no motion maps
            prob = motion["prob"][0, :, 0].double().numpy() if motion else np.zeros((0,))
            binary = motion["binary"][0, :, 0].numpy() if motion else np.zeros((0,))
            for j in range(prob.shape[0]):
                save_grey(os.path.join(d, f"motion_{j:02d}.png"), prob[j])
                save_mask(os.path.join(d, f"mask_{j:02d}.png"), binary[j])
            if "refined_input" in out:
                refined = out["refined_input"][0, :, 0].numpy() > 0.5
                for j in range(refined.shape[0]):
                    save_mask(os.path.join(d, f"refined_{j:02d}.png"), refined[j])
            with open(os.path.join(d, "cameras.json"), "w", encoding="utf-8") as f:
                json.dump(self.cameras_json(), f, indent=1)
            if self.labels:
                maps = self.label_maps.numpy()
                for j in range(maps.shape[0]):
                    m = maps[j]
                    counts = np.bincount(m.reshape(-1), minlength=len(self.labels))
                    share = counts / float(m.size)
                    save_label_map(os.path.join(d, f"labels_{j:02d}.png"), m, self.labels,
                                   cfg.image_height, cfg.image_width)
                    doc = {
                        "view": j,
                        "resolution": [int(m.shape[0]), int(m.shape[1])],
                        "logit_scale": 1.0 / 0.07,
                        "legend": {name: "#%02x%02x%02x" % palette_colour(k)
                                   for k, name in enumerate(self.labels)},
                        "labels": [{"index": k, "label": name, "colour": list(palette_colour(k)),
                                    "pixels": int(counts[k]), "share": float(share[k])}
                                   for k, name in enumerate(self.labels)],
                    }
                    with open(os.path.join(d, f"labels_{j:02d}.json"), "w", encoding="utf-8") as f:
                        json.dump(doc, f, indent=1)
            if self.render_mode == "path" and rgb.shape[0] > 1:
                # a smooth camera move: also an animation (as spar render writes it)
                from .images import save_path_animation
                pngs = [os.path.join(d, f"labels_{j:02d}.png") for j in range(rgb.shape[0])]
                save_path_animation(os.path.join(d, "path.gif"), rgb, pngs if self.labels else None)
            if self.want_features:
                feat = out["semantic_features"][0].float().numpy()
                for j in range(feat.shape[0]):
                    np.save(os.path.join(d, f"features_{j:02d}.npy"), feat[j].astype(np.float32))
        with open(os.path.join(d, "report.json"), "w", encoding="utf-8") as f:
            json.dump(self.report(), f, indent=1)

    def write_goldens(self, d: str) -> None:
        from .goldens import flatten, write_goldens
        arrays = [("images", self.images)]
        arrays += [(k, v) for k, v in flatten(self.out)]
        if self.labels:
            arrays += [("text_tokens", self.text_ids), ("text_embeddings", self.text_emb),
                       ("label_logits", self.label_logits), ("label_maps", self.label_maps)]
        header = {
            "precision": "fp64" if self.float64 else "fp32",
            "config": self.cfg.to_dict(),
            "order": self.order(), "inputs": list(self.inputs), "targets": list(self.targets),
            "render": self.render_mode,
            "assume_static": self.assume_static,
            "image_preparation": "images.py: PIL RGB, Lanczos cover-resize, centre crop, /255",
        }
        if self.labels:
            header["labels"] = list(self.labels)
            header["bpe"] = os.path.abspath(self.bpe)
        with self.timer("write_outputs"):
            write_goldens(d, arrays, self.float64, header)
        with open(os.path.join(d, "report.json"), "w", encoding="utf-8") as f:
            json.dump(self.report(), f, indent=1)


# ============================================================================ commands
def test_checkpoint(cfg, seed: int, perturb: bool, optimizer_state: bool, backbone_init: bool = True) -> Dict[str, Any]:
    """What make-checkpoint saves: the official training checkpoint of random weights from
    ``seed`` (spar.make_checkpoint), with CLIP's text tower where the model has LSeg.
    ``backbone_init``: as make_checkpoint has it."""
    from .spar import make_checkpoint
    ck = make_checkpoint(cfg, seed=seed, perturb=perturb, optimizer_state=optimizer_state,
                         backbone_init=backbone_init)
    if cfg.use_lseg:
        add_clip_text(ck, cfg, seed + 13, perturb)
    return ck


def cmd_make_checkpoint(args) -> int:
    cfg = get_config(args.config, None)
    out = os.path.abspath(args.output)
    if not os.path.isdir(os.path.dirname(out)):
        raise CliError(f"parent directory does not exist: {os.path.dirname(out)}")
    save_checkpoint(test_checkpoint(cfg, args.seed, args.perturb, not args.no_optimizer), out)
    return 0


def cmd_make_sam2_checkpoint(args) -> int:
    from spar_convert.sam2_config import Sam2ConfigError, read_sam2_config
    from .sam2 import make_checkpoint as make_sam2, video_path_shapes
    try:
        cfg = read_sam2_config(args.variant)
    except Sam2ConfigError as e:
        raise CliError(str(e))
    out = os.path.abspath(args.output)
    if not os.path.isdir(os.path.dirname(out)):
        raise CliError(f"parent directory does not exist: {os.path.dirname(out)}")
    # an official variant's file holds the video path too; a YAML-described test variant not
    # (its decoder width need not be the official 256)
    unused = video_path_shapes() if cfg.d_model == 256 else {}
    save_checkpoint(make_sam2(cfg, args.seed, unused), out)
    return 0


def save_checkpoint(ck: Dict[str, Any], out: str) -> None:
    """torch.save(ck) to ``out`` through a temporary file beside it (no partial file)."""
    import torch
    out = os.path.abspath(out)
    parent = os.path.dirname(out)
    fd, tmp = tempfile.mkstemp(prefix=os.path.basename(out) + ".tmp-", dir=parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    try:
        torch.save(ck, tmp)
        os.replace(tmp, out)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def cmd_render(args, state_dict=None) -> int:
    run = Run(args, goldens=False)
    run.compute(state_dict)
    with staged_dir(run.out_path) as d:
        run.write_render(d)
    return 0


def cmd_goldens(args, state_dict=None) -> int:
    run = Run(args, goldens=True)
    run.compute(state_dict)
    with staged_dir(run.out_path) as d:
        run.write_goldens(d)
    return 0


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line on stderr (exit code 2)."""

    def error(self, message):
        sys.stderr.write(f"{PROG}: error: {message} (see {self.prog} --help)\n")
        sys.exit(2)


def _threads(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return n


def _add_threads_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--threads", type=_threads, default=2, metavar="N",
                   help="torch threads (default 2)")


def _add_run_args(p: argparse.ArgumentParser, render: bool) -> None:
    p.add_argument("--checkpoint", required=True, metavar="X.pt",
                   help="SPAR training checkpoint ({'model': state_dict, ...} or a state_dict)")
    p.add_argument("--config", metavar="tiny|full|PATH",
                   help="model config (preset or YAML/JSON); default: inferred from the "
                        "checkpoint's tensor sizes (matching a preset)")
    views = p.add_mutually_exclusive_group(required=True)
    views.add_argument("--images", nargs="+", metavar="IMG",
                       help="input views; the sequence is these images then --targets")
    views.add_argument("--frames", nargs="+", metavar="IMG",
                       help="all frames in capture order; --inputs says which are inputs, "
                            "the rest are targets")
    p.add_argument("--targets", nargs="+", metavar="IMG",
                   help="target views (after --images in the sequence)")
    p.add_argument("--inputs", metavar="I,J,...",
                   help="with --frames: positions of the input views (e.g. 0,3,4)")
    cams = p.add_mutually_exclusive_group()
    cams.add_argument("--cameras", metavar="transforms.json",
                      help="render these cameras (nerfstudio transforms.json, OpenGL c2w, "
                           "in the canonical view's frame) instead of the targets")
    cams.add_argument("--path", type=int, metavar="N",
                      help="render N cameras along the estimated input cameras (slerp "
                           "rotations, lerp positions) instead of the targets")
    p.add_argument("--labels", metavar='"a,b,..."',
                   help="comma-separated prompts: open-vocabulary label maps of the rendered "
                        "views (needs CLIP text weights in the checkpoint)")
    if render:
        p.add_argument("--features", action="store_true",
                       help="also write the semantic features of each rendered view "
                            "(features_XX.npy, C x H/2 x W/2 float32)")
    p.add_argument("--bpe", metavar="PATH",
                   help=f"CLIP BPE merges table (default $SPAR_CLIP_BPE or {DEFAULT_BPE})")
    p.add_argument("--assume-static", action="store_true",
                   help="declare the scene static: skip DINOv3 and CV-DRP, gate no token, "
                        "write no motion maps")
    p.add_argument("--sam2", metavar="SAM2.pt",
                   help="a SAM2.1 checkpoint (official layout) for --refine / --mask-source refined")
    p.add_argument("--sam2-config", metavar="NAME|YAML|JSON",
                   help="its variant (default: from the file name, else its tensor shapes)")
    p.add_argument("--refine", action="store_true",
                   help="refine every view's motion mask with SAM2.1 (inputs and targets, as the "
                        "official _sam2_refine_masks): refined_XX.png beside mask_XX.png")
    p.add_argument("--mask-source", choices=("raw", "refined"), default="raw",
                   help="the masks that gate the input tokens: CV-DRP's (raw) or the refined hard "
                        "masks (implies --refine)")
    p.add_argument("--float64", action="store_true", help="run the model in float64")
    _add_threads_arg(p)
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output directory (must not exist; written as DIR.tmp-XXXX, renamed)")


def cmd_batch(args) -> int:
    """Runs the command lines of a JSON file (a list of argument lists, each one of this
    program's commands but batch) one after another in this process, every one even if an
    earlier one failed: one start of PyTorch for all of them (the engine's end-to-end tests
    compare with a dozen runs, where each process of its own spent about 1.5 s importing torch).
    A run's errors are its own one-line messages; the batch fails if any run did."""
    try:
        with open(args.file, encoding="utf-8") as f:
            runs = json.load(f)
    except (OSError, ValueError) as e:
        raise CliError(f"cannot read {args.file}: {e}")
    if not isinstance(runs, list) or not all(
            isinstance(r, list) and r and all(isinstance(a, str) for a in r) for r in runs):
        raise CliError(f"{args.file}: must hold a JSON list of argument lists")
    failed = []
    for i, argv in enumerate(runs):
        if argv[0] == "batch":
            raise CliError(f"{args.file}: run {i} is a batch")
        try:
            code = main(argv, interrupt_raises=True)  # Ctrl-C ends the batch, not only this run
        except SystemExit as e:  # a usage error: its one line is written already
            code = e.code if isinstance(e.code, int) else 2
        if code != 0:
            failed.append(f"run {i} ({argv[0]}, exit {code})")
    if failed:
        raise CliError(f"{len(failed)} of {len(runs)} runs failed: " + ", ".join(failed))
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(prog=PROG, description="PyTorch reference of SPAR: checkpoints, runs, goldens.")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    p = sub.add_parser("make-checkpoint", help="write a checkpoint as the official training does",
                       description="A checkpoint as the official training saves it "
                       "(torch.save of {model, optimizer, lr_scheduler, fwdbwd_pass_step, "
                       "param_update_step}), with the official initialization from --seed, "
                       "the frozen DINOv3 and LSeg references, and CLIP text weights under "
                       f"{CLIP_PREFIX}*.")
    p.add_argument("--config", required=True, metavar="tiny|full|PATH")
    p.add_argument("-o", "--output", required=True, metavar="X.pt")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--perturb", action="store_true",
                   help="random biases, norm weights, BatchNorm statistics, LayerScale, pose "
                        "heads (weights a test can see through)")
    p.add_argument("--no-optimizer", action="store_true",
                   help="no Adam moments in the optimizer state (param groups only): smaller")
    _add_threads_arg(p)
    p.set_defaults(func=cmd_make_checkpoint)

    p = sub.add_parser("make-sam2-checkpoint", help="write a SAM2.1 checkpoint in the official layout",
                       description="A SAM2.1 checkpoint ({'model': state_dict}, the official "
                       "keys of the variant) with random weights of sensible scale from --seed: "
                       "every tensor of the refinement path, the discarded heads, and for the "
                       "official widths the video path's tensors. For tests of spar-convert --sam2 "
                       "and the engine; not a trained model.")
    p.add_argument("--variant", required=True, metavar="NAME|YAML",
                   help="sam2.1_hiera_t, _s, _b+, _l, or a YAML in the official layout")
    p.add_argument("-o", "--output", required=True, metavar="SAM2.pt")
    p.add_argument("--seed", type=int, default=0)
    _add_threads_arg(p)
    p.set_defaults(func=cmd_make_sam2_checkpoint)

    p = sub.add_parser("render", help="run the reference and write images, masks, cameras",
                       description="Run SPAR on one ordered sequence of views and write "
                       "view_XX.png (rendered views), motion_XX.png / mask_XX.png (input "
                       "views), cameras.json, report.json, and with --labels labels_XX.png/"
                       ".json, with --features features_XX.npy.")
    _add_run_args(p, render=True)
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("goldens", help="write every stage's output as .npy with a manifest",
                       description="Run SPAR like render and write the prepared images and "
                       "every stage's output as .npy (float32, float64 with --float64, ints as "
                       "int32) plus manifest.json.")
    _add_run_args(p, render=False)
    p.set_defaults(func=cmd_goldens)

    p = sub.add_parser("batch", help="run the command lines of a JSON file in one process",
                       description="Run every command line of FILE (a JSON list of argument "
                       "lists, e.g. [[\"render\", \"--checkpoint\", ...], [\"goldens\", ...]]) in "
                       "order, in this process: PyTorch is imported once. Exit 1 if any run failed.")
    p.add_argument("file", metavar="FILE")
    p.set_defaults(func=cmd_batch, threads=1)
    return ap


def main(argv: Optional[Sequence[str]] = None, state_dict: Optional[Dict[str, Any]] = None, *,
         interrupt_raises: bool = False) -> int:
    """The command line. ``state_dict`` (render and goldens, in-process callers): the tensors of
    --checkpoint, which the caller holds already (tests/python/make_spar_goldens.py --full).
    ``interrupt_raises``: a KeyboardInterrupt goes on to the caller (batch) instead of ending
    this run alone."""
    args = build_parser().parse_args(argv)
    try:
        import torch
        torch.set_num_threads(args.threads)
        if state_dict is not None:
            return int(args.func(args, state_dict) or 0)
        return int(args.func(args) or 0)
    except CliError as e:
        sys.stderr.write(f"{PROG}: error: {_one_line(e)}\n")
        return 1
    except KeyboardInterrupt:
        if interrupt_raises:
            raise
        sys.stderr.write(f"{PROG}: error: interrupted\n")
        return 1
    except Exception as e:  # unexpected: still one line, no traceback
        sys.stderr.write(f"{PROG}: error: {e.__class__.__name__}: {_one_line(e)}\n")
        return 1


if __name__ == "__main__":
    sys.exit(main())
