"""Cameras in SPAR's convention: OpenCV axes (x right, y down, z forward), c2w [4, 4],
intrinsics normalized by the image size (fx/W, fy/H, cx/W, cy/H), pixel centres at
(x + 0.5, y + 0.5): exactly what spar_reference.spar.plucker_rays assumes.

The world has y UP (floor at y = 0); a camera's y axis points down in it.
"""

import numpy as np

WORLD_UP = np.array([0.0, 1.0, 0.0])


def look_at(eye, target, roll: float = 0.0) -> np.ndarray:
    """OpenCV c2w looking from ``eye`` at ``target`` with the world's up as -y, then rolled
    by ``roll`` radians about the viewing axis."""
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, WORLD_UP)          # right-handed: x = z x up (looking down -z gives +x)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)                 # points down
    if roll:
        c, s = np.cos(roll), np.sin(roll)
        x, y = c * x + s * y, -s * x + c * y
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, eye
    return m


def intrinsics(focal_norm: float, width: int, height: int) -> np.ndarray:
    """Square pixels, principal point at the centre: pixel focal = focal_norm * W for both
    axes, so fy/H differs from fx/W on non-square images."""
    f = focal_norm * width
    return np.array([f / width, f / height, 0.5, 0.5])


def pixel_rays(c2w: np.ndarray, k_norm, width: int, height: int) -> np.ndarray:
    """World directions [H*W, 3] (row-major pixels) with camera-frame z = 1."""
    fx, fy, cx, cy = (float(k_norm[0]) * width, float(k_norm[1]) * height,
                      float(k_norm[2]) * width, float(k_norm[3]) * height)
    ys, xs = np.meshgrid(np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64),
                         indexing="ij")
    dc = np.stack([(xs.ravel() + 0.5 - cx) / fx, (ys.ravel() + 0.5 - cy) / fy,
                   np.ones(width * height)], axis=1)
    return dc @ c2w[:3, :3].T


def project(points, c2w, k_norm, width: int, height: int):
    """World points [N, 3] -> (pixel coordinates [N, 2] as continuous (x, y) with pixel i
    covering [i, i+1), z-depth [N])."""
    pts = np.atleast_2d(np.asarray(points, dtype=np.float64))
    r, t = c2w[:3, :3], c2w[:3, 3]
    pc = (pts - t) @ r                  # = R^T (p - t)
    fx, fy = k_norm[0] * width, k_norm[1] * height
    cx, cy = k_norm[2] * width, k_norm[3] * height
    x = fx * pc[:, 0] / pc[:, 2] + cx
    y = fy * pc[:, 1] / pc[:, 2] + cy
    return np.stack([x, y], axis=1), pc[:, 2]


def trajectory(rng: np.random.Generator, center, n_frames: int, radius: float,
               height: float, phi0: float, half_arc: float, target) -> np.ndarray:
    """A smooth arc of camera positions around the room's centre (at ``radius``, angles
    phi0 -+ half_arc), all looking at ``target``, with small seeded jitter of position, aim
    and roll so that no two steps are exactly alike. Returns c2w [F, 4, 4]."""
    out = []
    for i in range(n_frames):
        s = 0.0 if n_frames == 1 else i / (n_frames - 1) * 2 - 1
        phi = phi0 + s * half_arc
        eye = np.array([center[0] + radius * np.cos(phi), height + 0.05 * s,
                        center[2] + radius * np.sin(phi)])
        eye = eye + rng.normal(0, 0.02, 3)
        aim = np.asarray(target, dtype=np.float64) + rng.normal(0, 0.04, 3)
        out.append(look_at(eye, aim, roll=float(rng.normal(0, 0.015))))
    return np.stack(out)


def relative_to(c2ws: np.ndarray, index: int) -> np.ndarray:
    """Poses in the frame of view ``index`` (that view becomes the identity), as SPAR's
    canonical view is."""
    inv = np.linalg.inv(c2ws[index])
    return np.einsum("ij,njk->nik", inv, c2ws)
