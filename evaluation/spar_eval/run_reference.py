"""Evaluation of a SPAR checkpoint with the PyTorch reference (PROTOCOL.md).

The model is built the way ``spar-reference render`` builds it (spar_reference.cli:
load_checkpoint, get_config, split_state_dict, build_model, build_text_encoder), so the
numbers are the reference's own. Per scene and K: one forward over all F frames, the targets
rendered with their estimated cameras, motion masks of inputs and targets from CV-DRP, label
maps of the rendered semantic features with the scene's class names as prompts.
"""

import os
import statistics
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional, Sequence

import numpy as np

from . import metrics
from .protocol import ProtocolError, Scene, discover_scenes, read_scene, view_indices

MODES = ("default", "no-gating", "assume-static")
METRIC_KEYS = ("psnr", "ssim", "psnr_nearest_input", "ssim_nearest_input", "psnr_mean_colour",
               "mask_miou", "mask_iou_dynamic", "mask_recall", "sem_miou", "sem_accuracy")


class EvalError(Exception):
    """A user-facing error: one line."""


@dataclass
class Options:
    checkpoint: str
    scenes: str
    config: Optional[str] = None
    clip: Optional[str] = None
    bpe: Optional[str] = None
    views: Sequence[int] = (2, 3, 4)
    mode: str = "default"
    float64: bool = False
    max_scenes: Optional[int] = None


# ============================================================================ model
@dataclass
class LoadedModel:
    model: Any
    cfg: Any
    text_encoder: Any          # None for a model without semantic decoding
    bpe: Optional[str]
    dtype: Any
    _text_cache: Dict[tuple, Any] = field(default_factory=dict)

    @property
    def semantic(self) -> bool:
        return self.text_encoder is not None

    def text_embeddings(self, names: Sequence[str]):
        """CLIP text embeddings of the prompts (cached: every scene has the same classes)."""
        import torch
        from spar_reference.bpe import tokenize
        key = tuple(names)
        if key not in self._text_cache:
            ids = tokenize(list(names), self.bpe, self.text_encoder.context_length)
            with torch.no_grad():
                self._text_cache[key] = self.text_encoder(ids)
        return self._text_cache[key]


def load_clip_file(path: str) -> Dict[str, Any]:
    """CLIP text weights from a separate file: a spar-train teacher file ({"clip": state_dict,
    ...}) or a state_dict (bare, or inside {"model": ...}; keys bare or under the checkpoint's
    lseg_model.clip_pretrained. prefix). Read with the converter's restricted reader, as
    spar-reference reads checkpoints: no code stored in the file runs."""
    import torch
    from spar_convert.torch_checkpoint import CheckpointError, open_checkpoint
    from spar_reference.cli import CLIP_PREFIX, CLIP_TEXT_ROOTS
    if not os.path.isfile(path):
        raise EvalError(f"CLIP weights not found: {path}")
    sd, errors = None, []
    for key in ("clip", None):     # teacher file first, then a (wrapped) state_dict
        try:
            with open_checkpoint(path, key) as ck:
                sd = {k: torch.from_numpy(np.array(v.numpy(), copy=True))
                      for k, v in ck.state_dict.items()}
            break
        except CheckpointError as e:
            errors.append(_one_line(e))
        except Exception as e:
            raise EvalError(f"cannot read CLIP weights {path}: {_one_line(e)}")
    if sd is None:
        raise EvalError(f"cannot read CLIP weights: {errors[-1]}")
    out = {}
    for k, v in sd.items():
        sub = k[len(CLIP_PREFIX):] if k.startswith(CLIP_PREFIX) else k
        if sub.startswith(CLIP_TEXT_ROOTS):
            out[sub] = v
    if not out:
        raise EvalError(f"no CLIP text weights (token_embedding..., text_projection) in {path}")
    return out


def load_model(opts: Options) -> LoadedModel:
    import torch
    from spar_reference import cli as ref
    try:
        sd = ref.load_checkpoint(opts.checkpoint)
        cfg = ref.get_config(opts.config, sd, opts.checkpoint)
        model_sd, clip_sd = ref.split_state_dict(sd)
        model = ref.build_model(cfg, model_sd, opts.float64)
        text, bpe = None, None
        if cfg.semantic_decoding:
            if opts.clip:
                clip_sd = load_clip_file(opts.clip)
            elif not clip_sd:
                raise EvalError("this semantic model's checkpoint carries no CLIP text weights "
                                "(lseg_model.clip_pretrained.*): give --clip FILE")
            bpe = opts.bpe or ref.default_bpe()
            if not os.path.isfile(bpe):
                raise EvalError(f"CLIP merges table not found: {bpe} (give --bpe PATH)")
            text = ref.build_text_encoder(cfg, clip_sd, opts.float64)
    except ref.CliError as e:
        raise EvalError(str(e))
    dtype = torch.float64 if opts.float64 else torch.float32
    return LoadedModel(model, cfg, text, bpe, dtype)


# ============================================================================ one scene
@dataclass
class Prediction:
    rgb: np.ndarray                    # float64 [T, H, W, 3], the model's output in [0, 1]
    dynamic: Optional[np.ndarray]      # bool [F, H, W] (P > 0.5) or None (assume-static)
    labels: Optional[np.ndarray]       # int64 [T, H, W] or None (no semantics)
    seconds: float                     # forward + label maps


def predict(lm: LoadedModel, scene: Scene, inputs: List[int], targets: List[int], mode: str
            ) -> Prediction:
    import torch
    from spar_reference.clip_text import full_resolution_labels, label_logits
    h, w = scene.size
    # the model's device (spar-train evaluates a model in training on its GPU); the text
    # encoder stays on the CPU, results come back to it
    dev = next(lm.model.parameters()).device
    x = torch.from_numpy(scene.rgb.astype(np.float64) / 255.0).permute(0, 3, 1, 2)[None]
    x = x.to(device=dev, dtype=lm.dtype).contiguous()
    kwargs: Dict[str, Any] = {"semantic_head": lm.semantic}
    if mode == "assume-static":
        kwargs["assume_static"] = True
    elif mode == "no-gating":
        # CV-DRP still runs (its masks are scored) but P(dynamic) = 0 gates nothing
        kwargs["dynamic_mask"] = torch.zeros(1, len(inputs), 1, h, w, dtype=lm.dtype, device=dev)
    t0 = time.perf_counter()
    with torch.no_grad():
        out = lm.model(x, inputs, targets, **kwargs)
        labels = None
        if lm.semantic:
            txt = lm.text_embeddings(scene.class_names).to(dev)
            labels = full_resolution_labels(label_logits(out["semantic_features"][0], txt)).cpu()
    seconds = time.perf_counter() - t0
    rgb = out["rgb"][0].permute(0, 2, 3, 1).double().cpu().numpy()
    dynamic = None
    if out["cv_drp_input"] is not None:
        dynamic = np.zeros((scene.frames, h, w), bool)
        dynamic[inputs] = out["cv_drp_input"]["binary"][0, :, 0].cpu().numpy()
        dynamic[targets] = out["cv_drp_target"]["binary"][0, :, 0].cpu().numpy()
    return Prediction(rgb, dynamic, None if labels is None else labels.numpy().astype(np.int64),
                      seconds)


# ============================================================================ accumulation
class Accumulator:
    """The protocol's sums over all scenes of one K."""

    def __init__(self, n_classes: int):
        self.psnr: List[float] = []
        self.ssim: List[float] = []
        # PROTOCOL.md "Baselines", on the views the model's metrics keep
        self.copy_psnr: List[float] = []
        self.copy_ssim: List[float] = []
        self.mean_psnr: List[float] = []
        self.mask = np.zeros(4, np.int64)
        self.has_mask = False
        self.conf = np.zeros((n_classes, n_classes), np.int64)
        self.has_sem = False
        self.times: List[float] = []
        self.target_views = 0

    def add(self, scene: Scene, inputs: List[int], targets: List[int], pred: Prediction) -> None:
        self.times.append(pred.seconds)
        self.target_views += len(targets)
        mean_colour = metrics.mean_colour_image([scene.rgb_float(i) for i in inputs],
                                                scene.rgb_float(inputs[0]).shape)
        for j, t in enumerate(targets):
            static = ~scene.dynamic[t]
            gt = scene.rgb_float(t)
            copy = scene.rgb_float(metrics.nearest_input(t, inputs))
            p = metrics.psnr_static(pred.rgb[j], gt, static)
            if p is not None:
                self.psnr.append(p)
                self.copy_psnr.append(metrics.psnr_static(copy, gt, static))
                self.mean_psnr.append(metrics.psnr_static(mean_colour, gt, static))
            s = metrics.ssim_static(pred.rgb[j], gt, static)
            if s is not None:
                self.ssim.append(s)
                self.copy_ssim.append(metrics.ssim_static(copy, gt, static))
            if pred.labels is not None:
                self.has_sem = True
                evaluated, gt_cls = metrics.semantic_targets(scene.classes[t], static)
                self.conf += metrics.confusion(pred.labels[j], gt_cls, evaluated,
                                               self.conf.shape[0])
        if pred.dynamic is not None:
            self.has_mask = True
            for f in range(scene.frames):
                self.mask += metrics.mask_counts(pred.dynamic[f], scene.dynamic[f])

    def result(self, seconds: float) -> Dict[str, Any]:
        r: Dict[str, Any] = {
            "psnr": float(np.mean(self.psnr)) if self.psnr else None,
            "ssim": float(np.mean(self.ssim)) if self.ssim else None,
            "psnr_nearest_input": float(np.mean(self.copy_psnr)) if self.copy_psnr else None,
            "ssim_nearest_input": float(np.mean(self.copy_ssim)) if self.copy_ssim else None,
            "psnr_mean_colour": float(np.mean(self.mean_psnr)) if self.mean_psnr else None,
        }
        r.update(metrics.mask_scores(self.mask) if self.has_mask else
                 {"mask_miou": None, "mask_iou_dynamic": None, "mask_recall": None})
        r.update(metrics.semantic_scores(self.conf) if self.has_sem else
                 {"sem_miou": None, "sem_accuracy": None})
        # every target view of every scene, skipped ones included (as the engine counts them)
        r["target_views"] = self.target_views
        r["seconds"] = seconds
        r["ms_per_scene"] = 1000.0 * statistics.median(self.times) if self.times else None
        return r


# ============================================================================ the run
def load_scenes(opts: Options) -> List[Scene]:
    try:
        paths = discover_scenes(opts.scenes)
        if opts.max_scenes is not None:
            paths = paths[:opts.max_scenes]
        scenes = [read_scene(p) for p in paths]
    except ProtocolError as e:
        raise EvalError(str(e))
    frames = {s.frames for s in scenes}
    if len(frames) != 1:
        raise EvalError(f"scenes have different frame counts: {sorted(frames)}")
    names = {tuple(s.class_names) for s in scenes}
    if len(names) != 1:
        raise EvalError("scenes have different classes.json (one confusion matrix needs one "
                        "class list)")
    return scenes


def check_views(views: Sequence[int], n_frames: int) -> None:
    for k in views:
        try:
            view_indices(n_frames, k)
        except ProtocolError as e:
            raise EvalError(str(e))


def evaluate(opts: Options, log: Callable[[str], None] = lambda s: None) -> Dict[str, Any]:
    """The result document of PROTOCOL.md (runner "reference")."""
    if opts.mode not in MODES:
        raise EvalError(f"unknown mode {opts.mode}")
    scenes = load_scenes(opts)
    n_frames = scenes[0].frames
    check_views(opts.views, n_frames)
    lm = load_model(opts)
    want = (lm.cfg.image_height, lm.cfg.image_width)
    for s in scenes:
        if s.size != want:
            raise EvalError(f"{s.name}: {s.size[1]}x{s.size[0]} images, the model takes "
                            f"{want[1]}x{want[0]} (no resizing in evaluation)")
    n_classes = len(scenes[0].class_names)
    results: Dict[str, Any] = {}
    for k in opts.views:
        inputs, targets = view_indices(n_frames, k)
        acc = Accumulator(n_classes)
        t0 = time.perf_counter()
        for i, s in enumerate(scenes):
            acc.add(s, inputs, targets, predict(lm, s, inputs, targets, opts.mode))
            log(f"K={k} scene {i + 1}/{len(scenes)} {s.name}")
        results[str(k)] = acc.result(time.perf_counter() - t0)
    return {
        "format": "spar-eval", "version": 1,
        "model": os.path.abspath(opts.checkpoint),
        "runner": "reference",
        "precision": "float64" if opts.float64 else "fp32",
        "mode": opts.mode,
        "scenes": len(scenes), "frames": n_frames,
        "results": results,
    }


def _one_line(e: BaseException) -> str:
    s = str(e).strip().replace("\n", " ")
    return s if s else e.__class__.__name__
