"""Scene folders on disk: PNGs per frame, scene.json, classes.json, transforms.json.

  rgb_XX.png      RGB, 8 bit
  class_XX.png    palette-indexed PNG: the stored value is the class id (classes.json),
                  the palette shows classes.PALETTE colours
  mask_XX.png     motion mask, 8-bit grey 0 / 255
  depth.npy       (optional) float32 [F, H, W] z-depth in world units
  scene.json      everything about the scene (see README.md)
  classes.json    [{id, name, color, dynamic}]
  transforms.json nerfstudio cameras in the canonical view's frame (view F // 2 = identity,
                  OpenGL c2w = OpenCV c2w @ diag(1, -1, -1, 1)), what ``spar render --cameras``
                  and ``spar-reference render --cameras`` read
A folder is written as DIR.tmp-XXXX and renamed when complete, so a failure leaves nothing.
"""

import json
import os
import shutil
import tempfile
from contextlib import contextmanager

import numpy as np
from PIL import Image

from .classes import PALETTE, classes_json

FORMAT = "spar-scenes"
VERSION = 1
GL_CV = np.diag([1.0, -1.0, -1.0, 1.0])


@contextmanager
def staged_dir(path: str):
    parent = os.path.dirname(os.path.abspath(path))
    tmp = tempfile.mkdtemp(prefix=os.path.basename(os.path.abspath(path)) + ".tmp-", dir=parent)
    try:
        yield tmp
        os.rename(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _palette_png(ids: np.ndarray) -> Image.Image:
    im = Image.fromarray(ids.astype(np.uint8), mode="P")
    flat = [c for rgb in PALETTE for c in rgb]
    im.putpalette(flat + [0] * (768 - len(flat)))
    return im


def transforms_json(scene: dict) -> dict:
    f, h, w = scene["classes"].shape
    k = scene["fxfycxcy"][0]
    frames = []
    for i in range(f):
        frames.append({"file_path": f"rgb_{i:02d}.png",
                       "transform_matrix": (scene["c2w_canonical"][i] @ GL_CV).tolist()})
    return {"camera_model": "OPENCV", "w": w, "h": h, "fl_x": float(k[0] * w),
            "fl_y": float(k[1] * h), "cx": float(k[2] * w), "cy": float(k[3] * h),
            "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "frames": frames}


def scene_json(scene: dict, depth: bool) -> dict:
    f, h, w = scene["classes"].shape
    k = scene["fxfycxcy"][0]
    frames = []
    for i in range(f):
        frames.append({
            "index": i, "rgb": f"rgb_{i:02d}.png", "classes": f"class_{i:02d}.png",
            "mask": f"mask_{i:02d}.png",
            "c2w_opencv": scene["c2w"][i].tolist(),
            "c2w_opencv_canonical": scene["c2w_canonical"][i].tolist(),
            "has_distractors": bool(scene["has_distractors"][i]),
            "distractor_pixels": int(scene["mask"][i].sum())})
    out = {"format": FORMAT, "version": VERSION, "seed": scene["seed"], "kind": scene["kind"],
           "width": w, "height": h, "n_frames": f, "canonical_index": scene["canonical_index"],
           "intrinsics_normalized": {"fx": float(k[0]), "fy": float(k[1]), "cx": float(k[2]),
                                     "cy": float(k[3])},
           "intrinsics_pixels": {"fl_x": float(k[0] * w), "fl_y": float(k[1] * h),
                                 "cx": float(k[2] * w), "cy": float(k[3] * h)},
           "world": "y up, metres, floor at y = 0; c2w in OpenCV axes (x right, y down, z forward)",
           "classes": classes_json(),
           "frames_with_distractors": [i for i in range(f) if scene["has_distractors"][i]],
           "frames": frames, "depth": "depth.npy" if depth else None}
    if "source_seed" in scene:
        out["source_seed"] = scene["source_seed"]
    out.update({k: v for k, v in scene["info"].items() if k not in out})
    return out


def write_files(scene: dict, d: str, depth: bool = False) -> None:
    """Write a scene into the existing directory d."""
    for i in range(scene["rgb"].shape[0]):
        Image.fromarray(scene["rgb"][i]).save(os.path.join(d, f"rgb_{i:02d}.png"))
        _palette_png(scene["classes"][i]).save(os.path.join(d, f"class_{i:02d}.png"))
        Image.fromarray(scene["mask"][i].astype(np.uint8) * 255).save(
            os.path.join(d, f"mask_{i:02d}.png"))
    if depth:
        np.save(os.path.join(d, "depth.npy"), scene["depth"].astype(np.float32))
    for name, obj in (("scene.json", scene_json(scene, depth)), ("classes.json", classes_json()),
                      ("transforms.json", transforms_json(scene))):
        with open(os.path.join(d, name), "w", encoding="utf-8") as fh:
            json.dump(obj, fh, indent=1)
            fh.write("\n")


def write_scene(scene: dict, path: str, depth: bool = False) -> None:
    """A new scene folder at ``path`` (must not exist)."""
    with staged_dir(path) as d:
        write_files(scene, d, depth)


def read_scene(path: str) -> dict:
    """A scene folder back into arrays (rgb, classes, mask, c2w, c2w_canonical, fxfycxcy)
    plus the parsed scene.json under "json"."""
    with open(os.path.join(path, "scene.json"), encoding="utf-8") as fh:
        meta = json.load(fh)
    fr = meta["frames"]
    k = meta["intrinsics_normalized"]
    return {
        "rgb": np.stack([np.array(Image.open(os.path.join(path, x["rgb"])).convert("RGB")) for x in fr]),
        "classes": np.stack([np.array(Image.open(os.path.join(path, x["classes"]))) for x in fr]),
        "mask": np.stack([np.array(Image.open(os.path.join(path, x["mask"]))) > 127 for x in fr]),
        "c2w": np.array([x["c2w_opencv"] for x in fr]),
        "c2w_canonical": np.array([x["c2w_opencv_canonical"] for x in fr]),
        "fxfycxcy": np.tile([k["fx"], k["fy"], k["cx"], k["cy"]], (len(fr), 1)),
        "json": meta}
