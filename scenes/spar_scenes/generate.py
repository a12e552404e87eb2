"""In-memory scenes: ``generate_scene`` renders a seed's room over a camera arc,
``copy_paste`` pastes one scene's distractor cut-outs onto another (static) scene.

Both return a dict of numpy arrays (plus a few plain values) that a training loop can use
directly:
  rgb        uint8 [F, H, W, 3]
  classes    uint8 [F, H, W]      class ids (classes.CLASS_NAMES)
  mask       bool  [F, H, W]      motion mask: a distractor is the nearest hit (or was pasted)
  depth      float32 [F, H, W]    z-depth in world units (the static scene's for copy-paste)
  c2w        float64 [F, 4, 4]    OpenCV camera-to-world in the world frame (y up, metres)
  c2w_canonical float64 [F, 4, 4] the same relative to the canonical view F // 2 (identity)
  fxfycxcy   float64 [F, 4]       normalized intrinsics (fx/W, fy/H, cx/W, cy/H)
  has_distractors bool [F]        whether the frame's mask has any pixel
  seed, kind ("dynamic" | "static" | "copy-paste"), canonical_index, class_names, info (dict
  for scene.json: room size, objects, distractors; source seed and shifts for copy-paste)
  _world      (generate_scene only) the world.World that was rendered, for tests and tools
"""

from typing import Tuple, Union

import numpy as np

from .camera import relative_to
from .classes import CLASS_NAMES
from .render import render_frame
from .world import TAKE_ROOM_FRAMES, build_world, reshoot


def parse_size(size: Union[int, Tuple[int, int]]) -> Tuple[int, int]:
    """128 -> (128, 128); (height, width) as given."""
    if isinstance(size, (int, np.integer)):
        hw = (int(size), int(size))
    else:
        hw = tuple(int(s) for s in size)
    if len(hw) != 2 or min(hw) < 1:
        raise ValueError(f"size must be a positive int or (height, width), got {size!r}")
    return hw


def generate_scene(seed: int, n_frames: int = 8, size=128, distractors: bool = True, take: int = 0) -> dict:
    """Render scene ``seed`` (any int >= 0). ``distractors=False`` gives the static version:
    the same room and cameras with nobody in it (a clean background for every frame).
    ``take`` >= 1: the same room, furniture and movers from another camera arc and at other
    moments (world.reshoot; the room is the one of the seed's 8-frame scene)."""
    if n_frames < 1:
        raise ValueError("n_frames must be >= 1")
    if seed < 0:
        raise ValueError("seed must be >= 0")
    if take < 0:
        raise ValueError("take must be >= 0")
    h, w = parse_size(size)
    if take:
        world = reshoot(build_world(int(seed), TAKE_ROOM_FRAMES, w, h, distractors=True), int(take),
                        int(n_frames), distractors=distractors)
    else:
        world = build_world(int(seed), int(n_frames), w, h, distractors=distractors)
    frames = [render_frame(world, f) for f in range(n_frames)]
    out = {k: np.stack([fr[k] for fr in frames]) for k in ("rgb", "classes", "mask", "depth")}
    canon = n_frames // 2
    out.update({
        "c2w": world.c2w.copy(),
        "c2w_canonical": relative_to(world.c2w, canon),
        "fxfycxcy": np.tile(world.k_norm, (n_frames, 1)),
        "has_distractors": out["mask"].reshape(n_frames, -1).any(axis=1),
        "seed": int(seed),
        "take": int(take),
        "kind": "dynamic" if distractors else "static",
        "canonical_index": canon,
        "class_names": list(CLASS_NAMES),
        "info": {"room_size": world.hi.tolist(), "light": world.light.tolist(),
                 "objects": world.objects, "distractors": world.distractors,
                 "windows_doors": [{"class": CLASS_NAMES[d.cls], "wall": d.face,
                                    "along": [d.a0, d.a1], "heights": [d.y0, d.y1]}
                                   for d in world.decals]},
        "_world": world,
    })
    return out


def shift(img: np.ndarray, dx: int, dy: int) -> np.ndarray:
    """out[y, x] = img[y - dy, x - dx] where that is inside the image, else 0."""
    out = np.zeros_like(img)
    h, w = img.shape[:2]
    ys, yd = (slice(0, h - dy), slice(dy, h)) if dy >= 0 else (slice(-dy, h), slice(0, h + dy))
    xs, xd = (slice(0, w - dx), slice(dx, w)) if dx >= 0 else (slice(-dx, w), slice(0, w + dx))
    if abs(dx) < w and abs(dy) < h:
        out[yd, xd] = img[ys, xs]
    return out


def copy_paste(static: dict, source: dict, seed: int = 0, max_shift: float = 0.25) -> dict:
    """The paper's copy-paste augmentation: in every frame, the pixels of ``source``'s motion
    mask (its distractor cut-outs) are pasted onto ``static``'s frame, moved by an offset
    that drifts from frame to frame (so the pasted object moves relative to the room); the
    pasted mask is the ground truth. Cameras, intrinsics and depth are the static scene's.
    Needs the same number of frames and image size."""
    if static["rgb"].shape != source["rgb"].shape:
        raise ValueError(f"copy_paste: shapes differ: {static['rgb'].shape} vs {source['rgb'].shape}")
    f, h, w = static["classes"].shape
    rng = np.random.default_rng([int(seed), 3])
    base = rng.uniform(-max_shift, max_shift, 2) * (w, h)
    vel = rng.uniform(-0.04, 0.04, 2) * (w, h)
    shifts = np.round(base[None] + np.arange(f)[:, None] * vel[None]).astype(int)   # [F, (dx, dy)]
    rgb, cls, mask = static["rgb"].copy(), static["classes"].copy(), np.zeros((f, h, w), bool)
    for i, (dx, dy) in enumerate(shifts):
        m = shift(source["mask"][i], dx, dy)
        mask[i] = m
        rgb[i][m] = shift(source["rgb"][i], dx, dy)[m]
        cls[i][m] = shift(source["classes"][i], dx, dy)[m]
    out = {k: v for k, v in static.items() if k not in ("rgb", "classes", "mask", "_world")}
    out.update({"rgb": rgb, "classes": cls, "mask": mask,
                "has_distractors": mask.reshape(f, -1).any(axis=1), "kind": "copy-paste",
                "source_seed": int(source["seed"]), "shifts": shifts,
                "info": dict(static["info"], source_seed=int(source["seed"]),
                             paste_seed=int(seed), shifts_xy=shifts.tolist())})
    return out
