"""The test set side of the protocol (PROTOCOL.md): which scene folders, which frames are
inputs and targets, and a scene folder read into arrays."""

import json
import os
from dataclasses import dataclass
from typing import List, Tuple

import numpy as np


class ProtocolError(Exception):
    """The test set does not follow the protocol (a one-line message for the user)."""


def view_indices(n_frames: int, k: int) -> Tuple[List[int], List[int]]:
    """(inputs, targets) for K input views of F frames: i_j = floor(j (F-1)/(K-1) + 1/2),
    targets the other frames in order. Integer arithmetic, so a tie (x.5) rounds up exactly
    as floor(x + 0.5) does, with no floating-point doubt:
    floor(j (F-1)/(K-1) + 1/2) = floor((2 j (F-1) + (K-1)) / (2 (K-1)))."""
    if k < 2:
        raise ProtocolError(f"need at least 2 input views, got K={k}")
    if k >= n_frames:
        raise ProtocolError(f"K={k} input views leave no target among {n_frames} frames")
    inputs = [(2 * j * (n_frames - 1) + (k - 1)) // (2 * (k - 1)) for j in range(k)]
    targets = [i for i in range(n_frames) if i not in inputs]
    return inputs, targets


def discover_scenes(root: str) -> List[str]:
    """The scene folders of a test set (sub-folders holding scene.json), sorted bytewise by
    name (os.fsencode, so the order does not depend on the locale)."""
    if not os.path.isdir(root):
        raise ProtocolError(f"scenes directory not found: {root}")
    names = [n for n in os.listdir(root)
             if os.path.isfile(os.path.join(root, n, "scene.json"))]
    if not names:
        raise ProtocolError(f"no scene folders (DIR/*/scene.json) in {root}")
    names.sort(key=os.fsencode)
    return [os.path.join(root, n) for n in names]


@dataclass
class Scene:
    name: str
    rgb: np.ndarray            # uint8 [F, H, W, 3]
    classes: np.ndarray        # int64 [F, H, W] class ids
    dynamic: np.ndarray        # bool [F, H, W] ground-truth motion mask (mask_XX.png > 127)
    class_names: List[str]     # prompts, index = class id

    @property
    def frames(self) -> int:
        return int(self.rgb.shape[0])

    @property
    def size(self) -> Tuple[int, int]:
        return int(self.rgb.shape[1]), int(self.rgb.shape[2])

    def rgb_float(self, i: int) -> np.ndarray:
        """Ground truth RGB of frame i as the protocol defines it: PNG value / 255."""
        return self.rgb[i].astype(np.float64) / 255.0


def _class_names(path: str) -> List[str]:
    with open(os.path.join(path, "classes.json"), encoding="utf-8") as f:
        doc = json.load(f)
    if not isinstance(doc, list) or not doc:
        raise ProtocolError("classes.json is not a non-empty list")
    try:
        entries = sorted((int(e["id"]), str(e["name"])) for e in doc)
    except (KeyError, TypeError, ValueError):
        raise ProtocolError("classes.json entries need id and name")
    if [i for i, _ in entries] != list(range(len(entries))):
        raise ProtocolError("classes.json ids are not 0 .. n-1")
    names = [n for _, n in entries]
    if len(set(names)) != len(names) or any("," in n or not n.strip() for n in names):
        raise ProtocolError("classes.json names must be distinct, non-empty, without commas")
    return names


def read_scene(path: str) -> Scene:
    """A scene folder as spar_scenes.writer wrote it (read with its own reader)."""
    from spar_scenes.writer import read_scene as read_folder
    name = os.path.basename(os.path.normpath(path))
    try:
        d = read_folder(path)
        names = _class_names(path)
    except ProtocolError as e:
        raise ProtocolError(f"{name}: {e}")
    except Exception as e:
        msg = str(e).strip().replace("\n", " ") or e.__class__.__name__
        raise ProtocolError(f"cannot read scene {name}: {msg}")
    rgb, classes, dyn = d["rgb"], d["classes"], d["mask"]
    if rgb.ndim != 4 or rgb.shape[-1] != 3 or classes.shape != rgb.shape[:3] \
            or dyn.shape != rgb.shape[:3]:
        raise ProtocolError(f"{name}: rgb / class / mask images of different sizes")
    if classes.size and int(classes.max()) >= len(names):
        raise ProtocolError(f"{name}: class id {int(classes.max())} has no name in classes.json")
    return Scene(name, rgb, classes.astype(np.int64), dyn.astype(bool), names)
