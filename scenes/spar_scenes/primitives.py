"""What a scene is made of: its primitives (geometry.py's shapes), the windows and doors on its
walls, and the world record that world.py builds and distractors.py adds moving primitives to."""

from dataclasses import dataclass, field
from typing import List

import numpy as np


@dataclass
class Prim:
    """One primitive (geometry.py): params [k] if static, [F, k] if it moves."""
    shape: str
    cls: int
    mat: dict
    params: np.ndarray
    dynamic: bool = False
    name: str = ""


@dataclass
class Decal:
    """A window or door: a textured rectangle on wall ``face`` spanning the along-wall
    coordinate [a0, a1] and heights [y0, y1]."""
    face: int
    cls: int
    mat: dict
    a0: float
    a1: float
    y0: float
    y1: float


@dataclass
class World:
    seed: int
    width: int
    height: int
    n_frames: int
    lo: np.ndarray
    hi: np.ndarray
    face_mats: List[dict]
    decals: List[Decal]
    prims: List[Prim]
    light: np.ndarray
    ambient: float
    c2w: np.ndarray                  # [F, 4, 4] OpenCV camera-to-world, world frame
    k_norm: np.ndarray               # [4] fx/W, fy/H, cx/W, cy/H
    objects: List[dict] = field(default_factory=list)      # description for scene.json
    distractors: List[dict] = field(default_factory=list)
    # What a re-shoot of the room needs (world.reshoot): the movers' parameters
    # (distractors.draw_movers), the furniture's (x, z) footprints and the camera arc's layout.
    movers: List[dict] = field(default_factory=list)
    footprints: List[tuple] = field(default_factory=list)
    arc: dict = field(default_factory=dict)
