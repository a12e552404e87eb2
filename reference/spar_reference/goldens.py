#!/usr/bin/python3
"""Golden files: every stage's output of one reference run as .npy files plus manifest.json.

Each tensor of ``SPAR.forward``'s output dict (with ``record_layers``) becomes one file named
after its key, nested keys joined by '.' (``cv_drp_input.prob.npy``,
``layers.transformer_decoder.01.npy``); float tensors as float32 (float64 with --float64),
integer and boolean tensors as int32, list-of-pairs as int32 [P, 2]. The tool adds the
prepared images, the text side and the label maps.

manifest.json::

    {"format": "spar-reference-goldens", "version": 1, "precision": "fp32" | "fp64",
     "config": {...SparConfig.to_dict()...},
     "order": [{"index": i, "file": path, "role": "input" | "target"}, ...],
     "inputs": [...], "targets": [...], "render": "targets" | "path" | "cameras",
     "labels": [...prompts...] (only with --labels),
     "files": [{"file": "rgb.npy", "name": "rgb", "stage": "rgb_head",
                "shape": [1, 2, 3, 128, 128], "dtype": "float32",
                "description": "..."}, ...]}

``stage`` is the pipeline stage the tensor belongs to (see STAGES); ``name`` the output key.
"""

import json
import os
from typing import Any, Dict, Iterator, List, Tuple

import numpy as np

# output key (first component) -> (stage, description)
STAGES: Dict[str, Tuple[str, str]] = {
    "images": ("inputs", "prepared images of all views in sequence order [V,3,H,W], [0,1]"),
    "input_idx": ("inputs", "indices of the input views in the sequence [B,K]"),
    "target_idx": ("inputs", "indices of the target views in the sequence [B,T]"),
    "img_tokens_raw": ("image_tokens", "image_tokenizer(2*img-1) [B,V,n,D]"),
    "pe_code": ("image_tokens", "sin-cos code (2D patch | 1D view index) fed to pe_embedder [V,n,D]"),
    "img_tokens": ("image_tokens", "image tokens + pe_embedder(code) [B,V,n,D]"),
    "cam_tokens_in": ("pose_encoder", "camera tokens cam_code + temporal_pe_embedder(code) [B,V,D]"),
    "pose_encoder_out": ("pose_encoder", "pose encoder output over [camera, image tokens] [B,V+V*n,D]"),
    "cam_tokens": ("pose_encoder", "camera tokens after the pose encoder [B,V,D]"),
    "cam_info": ("pose_head", "raw pose head output (6D rot, t, fx, fy, cx, cy) [B,V,13]"),
    "c2w": ("pose_head", "estimated camera-to-world, OpenCV axes, canonical frame [B,V,4,4]"),
    "fxfycxcy": ("pose_head", "estimated normalized intrinsics (fx/W, fy/H, cx/W, cy/H) [B,V,4]"),
    "plucker": ("rays", "Pluecker rays [o x d, d] of all views [B,V,6,H,W]"),
    "ray_tokens": ("rays", "target_pose_tokenizer(rays) of all views [B,V,n,D]"),
    "dino": ("dino", "DINOv3 patch tokens (normalized, CLS/registers dropped) [B,V,n,D]"),
    "cv_drp_input": ("cv_drp", "CV-DRP over the input views (pairs (i,i+1))"),
    "cv_drp_target": ("cv_drp", "CV-DRP over the target views (pairs (i,T-1-i))"),
    "dynamic_mask_input": ("gating", "P(dynamic) of the input views used for gating [B,K,1,H,W]"),
    "dynamic_patch": ("gating", "P(dynamic) average-pooled per patch [B,K*n]"),
    "static_patch": ("gating", "1 - dynamic_patch [B,K*n]"),
    "fused_tokens": ("gating", "mlp_fuse(image tok, ray tok) + view_type[0] [B,K*n,D]"),
    "gated_tokens": ("gating", "soft_with_pe gated input tokens [B,K*n,D]"),
    "lseg_features": ("lseg", "LSeg features of the input views [B,K,C,H/2,W/2]"),
    "semantic_in": ("semantic_tokens", "concat(LSeg features, rays at H/2) avg-pooled by 8 [B*K,C+6,H/16,W/16]"),
    "semantic_tokens": ("semantic_tokens", "semantic_proj(pooled) + view_type[0] [B,K*ns,D]"),
    "dynamic_patch_sem": ("semantic_tokens", "P(dynamic) average-pooled per 16x16 [B,K*ns]"),
    "gated_semantic_tokens": ("semantic_tokens", "gated semantic tokens [B,K*ns,D]"),
    "scene_encoder_in": ("scene_encoder", "[scene_code, gated image tokens, gated semantic tokens] [B,S+...,D]"),
    "scene_encoder_out": ("scene_encoder", "scene encoder output [B,S+...,D]"),
    "scene_tokens": ("scene_encoder", "first S tokens of the scene encoder output [B,S,D]"),
    "render_c2w": ("render_cameras", "cameras rendered, OpenCV c2w, canonical frame [B,R,4,4]"),
    "render_fxfycxcy": ("render_cameras", "normalized intrinsics of the rendered views [B,R,4]"),
    "render_plucker": ("render_cameras", "Pluecker rays of the rendered views [B,R,6,H,W]"),
    "rgb_queries": ("decoder", "target_pose_tokenizer2(rays) + view_type[1] [B,R,n,D]"),
    "semantic_queries": ("decoder", "target_pose_tokenizer_semantic(rays) + view_type[1] [B,R,n,D]"),
    "decoder_in": ("decoder", "decoder_ln([rgb queries, semantic queries, scene tokens]) [B*R,L,D]"),
    "decoder_out": ("decoder", "decoder output [B*R,L,D]"),
    "rgb_tokens": ("rgb_head", "decoded RGB tokens [B*R,n,D]"),
    "rgb": ("rgb_head", "rendered RGB in [0,1] [B,R,3,H,W]"),
    "semantic_out_tokens": ("semantic_head", "decoded semantic tokens [B*R,n,D]"),
    "semantic_hidden": ("semantic_head", "semantic_token_decoder unpatchified [B,R,64,H,W]"),
    "semantic_features": ("semantic_head", "semantic features after expansion [B,R,C,H/2,W/2]"),
    "layers": ("layers", "output of one transformer layer"),
    "text_tokens": ("text_encoder", "CLIP BPE token ids of the prompts [P,77]"),
    "text_embeddings": ("text_encoder", "CLIP text embeddings of the prompts (not normalized) [P,C]"),
    "label_logits": ("labels", "scale * <normalized features, normalized text> [R,P,H/2,W/2]"),
    "label_maps": ("labels", "argmax over the prompts of the logits x2 bilinear (align_corners) [R,H,W]"),
}

SUB_DESCRIPTIONS = {
    "logits": "per-view CV-DRP logits, averaged over pairs before the sigmoid [B,*,1,H,W]",
    "prob": "per-view P(dynamic) = sigmoid(logits) [B,*,1,H,W]",
    "binary": "motion mask prob > threshold (0/1) [B,*,1,H,W]",
    "pairs": "view pairs (i, j) within the subset [P,2]",
    "pair_fused": "fusion_mlp output per pair [P,B,2n,D]",
    "pair_tokens": "CV-DRP transformer output per pair [P,B,2n,D]",
    "pair_logits": "decoder logits per pair [P,B,2,1,H,W]",
    "transformer_encoder": "pose encoder layer output",
    "transformer_encoder_geom": "scene encoder layer output",
    "transformer_decoder": "decoder layer output",
}


def flatten(obj: Any, prefix: str = "") -> Iterator[Tuple[str, Any]]:
    """(dotted key, tensor / array / list of pairs) of a nested output dict; None skipped."""
    if obj is None:
        return
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from flatten(v, f"{prefix}.{k}" if prefix else str(k))
    elif isinstance(obj, (list, tuple)) and obj and not isinstance(obj[0], (int, tuple, list)):
        for i, v in enumerate(obj):
            yield from flatten(v, f"{prefix}.{i:02d}")
    else:
        yield prefix, obj


def to_numpy(x: Any, float64: bool) -> np.ndarray:
    try:
        import torch
        if isinstance(x, torch.Tensor):
            x = x.detach().cpu()
            if x.dtype == torch.bool or not x.is_floating_point():
                return x.to(torch.int32).numpy()
            return x.to(torch.float64 if float64 else torch.float32).numpy()
    except ImportError:  # pragma: no cover
        pass
    a = np.asarray(x)
    if a.dtype == bool or np.issubdtype(a.dtype, np.integer):
        return a.astype(np.int32)
    return a.astype(np.float64 if float64 else np.float32)


def describe(name: str) -> Tuple[str, str]:
    parts = name.split(".")
    stage, desc = STAGES.get(parts[0], ("other", "output " + name))
    if len(parts) > 1:
        sub = SUB_DESCRIPTIONS.get(parts[1])
        if parts[0] == "layers":
            stage = {"transformer_encoder": "pose_encoder", "transformer_encoder_geom":
                     "scene_encoder", "transformer_decoder": "decoder"}.get(parts[1], stage)
            desc = f"{sub or parts[1]} {int(parts[2])} [B,L,D]" if len(parts) > 2 else desc
        elif sub:
            desc = f"{desc}: {sub}"
    return stage, desc


def write_goldens(out_dir: str, arrays: List[Tuple[str, Any]], float64: bool,
                  header: Dict[str, Any]) -> Dict[str, Any]:
    """Save each (name, value) as <name>.npy in out_dir and write manifest.json."""
    files = []
    seen = set()
    for name, value in arrays:
        if name in seen:
            raise ValueError(f"duplicate golden {name}")
        seen.add(name)
        a = to_numpy(value, float64)
        fname = name + ".npy"
        np.save(os.path.join(out_dir, fname), a)
        stage, desc = describe(name)
        files.append({"file": fname, "name": name, "stage": stage, "shape": list(a.shape),
                      "dtype": str(a.dtype), "description": desc})
    manifest = {"format": "spar-reference-goldens", "version": 1}
    manifest.update(header)
    manifest["files"] = files
    with open(os.path.join(out_dir, "manifest.json"), "w", encoding="utf-8") as f:
        json.dump(manifest, f, indent=1)
    return manifest
