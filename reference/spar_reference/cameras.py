#!/usr/bin/python3
"""Camera conventions of the reference's command-line tool.

SPAR's cameras: c2w [4, 4] in OpenCV axes (camera x right, y down, z forward), in the frame
of the canonical view (index V//2 of the sequence, identity pose); intrinsics normalized by
the image size: (fx/W, fy/H, cx/W, cy/H), one focal for all views, cx = cy = 0.5.

nerfstudio transforms.json (what ``--cameras`` reads and ``cameras.json`` is written in):
``frames[i].transform_matrix`` is camera-to-world in OpenGL axes (x right, y up, z back);
``fl_x, fl_y, cx, cy, w, h`` in pixels, at the top level or per frame (a frame's own values
win). Conversion: c2w_opencv = transform_matrix @ diag(1, -1, -1, 1) (and back the same way).
Intrinsics given for a w x h image are carried through the image preparation rule
(``images.crop_geometry``: resize by nw/w, nh/h, crop at left, top) and then normalized by the
model's W, H; with w, h equal to the model size (as in our cameras.json) they are unchanged.
Missing fl_y = fl_x; missing cx, cy = w/2, h/2; missing w, h = the model size.
"""

import json
import math
from typing import Any, Dict, Optional, Sequence

import numpy as np

from .images import crop_geometry

GL_CV = np.diag([1.0, -1.0, -1.0, 1.0])


class CameraError(Exception):
    pass


def opengl_to_opencv(c2w: np.ndarray) -> np.ndarray:
    return np.asarray(c2w, dtype=np.float64) @ GL_CV


opencv_to_opengl = opengl_to_opencv  # the flip is its own inverse


def _num(d: Dict[str, Any], key: str, default: Optional[float], where: str) -> Optional[float]:
    v = d.get(key, default)
    if v is None:
        return None
    try:
        return float(v)
    except (TypeError, ValueError):
        raise CameraError(f"{where}: {key} is not a number")


def read_transforms(path: str, out_w: int, out_h: int):
    """nerfstudio transforms.json -> (c2w_opencv [R, 4, 4], fxfycxcy normalized [R, 4])."""
    try:
        with open(path, "r", encoding="utf-8") as f:
            data = json.load(f)
    except FileNotFoundError:
        raise CameraError(f"cameras file not found: {path}")
    except (OSError, ValueError) as e:
        raise CameraError(f"cannot read cameras file {path}: {e}")
    frames = data.get("frames") if isinstance(data, dict) else None
    if not isinstance(frames, list) or not frames:
        raise CameraError(f"{path}: no frames")
    c2ws, ks = [], []
    for i, fr in enumerate(frames):
        where = f"{path}: frames[{i}]"
        if not isinstance(fr, dict) or "transform_matrix" not in fr:
            raise CameraError(f"{where}: no transform_matrix")
        m = np.asarray(fr["transform_matrix"], dtype=np.float64)
        if m.shape == (3, 4):
            m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise CameraError(f"{where}: transform_matrix is not a finite 4x4 matrix")

        def get(key, default=None):
            return _num(fr, key, _num(data, key, default, where), where)
        w = get("w", out_w)
        h = get("h", out_h)
        fx = get("fl_x")
        if fx is None:
            raise CameraError(f"{where}: no fl_x")
        fy = get("fl_y", fx)
        cx = get("cx", w / 2.0)
        cy = get("cy", h / 2.0)
        if w <= 0 or h <= 0 or fx <= 0 or fy <= 0:
            raise CameraError(f"{where}: w, h, fl_x, fl_y must be positive")
        nw, nh, left, top = crop_geometry(int(round(w)), int(round(h)), out_w, out_h)
        sx, sy = nw / w, nh / h
        ks.append([fx * sx / out_w, fy * sy / out_h, (cx * sx - left) / out_w,
                   (cy * sy - top) / out_h])
        c2ws.append(opengl_to_opencv(m))
    return np.stack(c2ws), np.asarray(ks, dtype=np.float64)


def camera_entry(c2w_cv: np.ndarray, k_norm: Sequence[float], w: int, h: int,
                 **extra) -> Dict[str, Any]:
    """One frame of cameras.json: nerfstudio fields plus the SPAR-side values."""
    c2w_cv = np.asarray(c2w_cv, dtype=np.float64)
    fxn, fyn, cxn, cyn = (float(x) for x in k_norm)
    e = dict(extra)
    e.update({
        "transform_matrix": opencv_to_opengl(c2w_cv).tolist(),
        "fl_x": fxn * w, "fl_y": fyn * h, "cx": cxn * w, "cy": cyn * h, "w": w, "h": h,
        "intrinsics_normalized": {"fx": fxn, "fy": fyn, "cx": cxn, "cy": cyn},
        "c2w_opencv": c2w_cv.tolist(),
    })
    return e


# ---------------------------------------------------------------------------- rotations
def mat_to_quat(r: np.ndarray) -> np.ndarray:
    """Rotation matrix -> unit quaternion (w, x, y, z) (Shepperd's method)."""
    r = np.asarray(r, dtype=np.float64)
    t = np.trace(r)
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
        q = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif r[1, 1] > r[2, 2]:
        s = math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
    else:
        s = math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    return q / np.linalg.norm(q)


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def slerp(q0: np.ndarray, q1: np.ndarray, u: float) -> np.ndarray:
    """Shortest-arc spherical interpolation of unit quaternions."""
    d = float(np.dot(q0, q1))
    if d < 0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + u * (q1 - q0)
        return q / np.linalg.norm(q)
    th = math.acos(min(1.0, d))
    return (math.sin((1 - u) * th) * q0 + math.sin(u * th) * q1) / math.sin(th)


def interpolate_path(c2ws: np.ndarray, n: int) -> np.ndarray:
    """N cameras along the given ones (in their order): parameter t_j = j (K-1)/(N-1)
    (t = 0 for N = 1); between cameras i and i+1 (i = min(floor(t), K-2), u = t - i)
    the rotation is slerp(q_i, q_{i+1}, u), the position (1-u) t_i + u t_{i+1}. OpenCV c2w."""
    c2ws = np.asarray(c2ws, dtype=np.float64)
    k = c2ws.shape[0]
    quats = [mat_to_quat(c[:3, :3]) for c in c2ws]
    out = []
    for j in range(n):
        if k == 1:
            out.append(c2ws[0].copy())
            continue
        t = 0.0 if n == 1 else j * (k - 1) / (n - 1)
        i = min(int(math.floor(t)), k - 2)
        u = t - i
        m = np.eye(4)
        m[:3, :3] = quat_to_mat(slerp(quats[i], quats[i + 1], u))
        m[:3, 3] = (1 - u) * c2ws[i, :3, 3] + u * c2ws[i + 1, :3, 3]
        out.append(m)
    return np.stack(out)
