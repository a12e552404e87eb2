"""Ray / primitive intersections and surface frames, vectorized over rays.

Rays are o + t d with one origin (the camera centre, shape [3]) and directions d [N, 3]
whose camera-frame z component is 1, so t is the z-depth of the hit (what depth maps store).
Each ``*_t`` function returns t [N] with +inf where the ray misses; each ``*_surface``
function takes the hit points p [N, 3] and returns normals [N, 3] (unit, outwards) and
texture coordinates u, v [N] in metres.

Primitives (all axis-aligned, which is all furniture along axis-aligned walls needs):
  box       params (lo[3], hi[3])
  cylinder  params (cx, cz, y0, y1, r): vertical axis, closed caps
  ellipsoid params (c[3], r[3]): semi-axes along x, y, z (a sphere when equal)
"""

import numpy as np

EPS = 1e-6
INF = np.inf


def _safe_inv(d: np.ndarray) -> np.ndarray:
    # a direction component of exactly 0 would give 0 * inf = nan in the slab test
    d = np.where(np.abs(d) < 1e-12, 1e-12, d)
    return 1.0 / d


def box_slabs(o, inv_d, lo, hi):
    """Entry and exit t of the slab test: (t_near [N], t_far [N])."""
    t1 = (np.asarray(lo) - o) * inv_d
    t2 = (np.asarray(hi) - o) * inv_d
    return np.minimum(t1, t2).max(axis=1), np.maximum(t1, t2).min(axis=1)


def box_t(o, d, inv_d, lo, hi):
    """Nearest hit from outside (the camera is never inside an object)."""
    tn, tf = box_slabs(o, inv_d, lo, hi)
    return np.where((tn <= tf) & (tn > EPS), tn, INF)


def box_surface(p, lo, hi):
    lo, hi = np.asarray(lo), np.asarray(hi)
    # the face a point lies on is the one it is closest to
    err = np.concatenate([np.abs(p - lo), np.abs(p - hi)], axis=1)       # [N, 6]
    face = err.argmin(axis=1)
    axis = face % 3
    n = np.zeros_like(p)
    n[np.arange(len(p)), axis] = np.where(face < 3, -1.0, 1.0)
    u, v = _axis_uv(p, axis)
    return n, u, v


def _axis_uv(p, axis):
    """Coordinates across a face perpendicular to ``axis``: x-faces (z, -y), y-faces (x, z),
    z-faces (x, -y); -y so that v grows downwards on vertical faces like image rows."""
    u = np.where(axis == 0, p[:, 2], p[:, 0])
    v = np.where(axis == 1, p[:, 2], -p[:, 1])
    return u, v


def room_t(o, inv_d, lo, hi):
    """Rays from inside the room box: exit t and the face index 0..5 = (-x, -y, -z, +x, +y, +z)."""
    t1 = (np.asarray(lo) - o) * inv_d
    t2 = (np.asarray(hi) - o) * inv_d
    tf = np.maximum(t1, t2)
    axis = tf.argmin(axis=1)
    t = tf[np.arange(len(tf)), axis]
    pos = np.where(t2[np.arange(len(tf)), axis] >= t1[np.arange(len(tf)), axis], 1, 0)
    return t, axis + 3 * pos


def room_surface(p, face):
    """Inward normals of the room faces and their (u, v)."""
    axis = face % 3
    n = np.zeros_like(p)
    n[np.arange(len(p)), axis] = np.where(face < 3, 1.0, -1.0)
    u, v = _axis_uv(p, axis)
    return n, u, v


def cylinder_t(o, d, cx, cz, y0, y1, r):
    ox, oz = o[0] - cx, o[2] - cz
    dx, dz = d[:, 0], d[:, 2]
    a = dx * dx + dz * dz
    b = ox * dx + oz * dz
    c = ox * ox + oz * oz - r * r
    disc = b * b - a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        ts = (-b - np.sqrt(disc)) / a
    y = o[1] + ts * d[:, 1]
    side = np.where((disc >= 0) & (a > 1e-12) & (ts > EPS) & (y >= y0) & (y <= y1), ts, INF)
    best = side
    inv_dy = _safe_inv(d[:, 1])
    for yc in (y0, y1):
        tc = (yc - o[1]) * inv_dy
        x = o[0] + tc * d[:, 0] - cx
        z = o[2] + tc * d[:, 2] - cz
        cap = np.where((tc > EPS) & (x * x + z * z <= r * r), tc, INF)
        best = np.minimum(best, cap)
    return best


def cylinder_surface(p, cx, cz, y0, y1, r):
    dx, dz = p[:, 0] - cx, p[:, 2] - cz
    rad = np.sqrt(dx * dx + dz * dz)
    cap_err = np.minimum(np.abs(p[:, 1] - y0), np.abs(p[:, 1] - y1))
    on_cap = cap_err < np.abs(rad - r)
    n = np.zeros_like(p)
    safe = np.maximum(rad, 1e-12)
    n[:, 0] = np.where(on_cap, 0.0, dx / safe)
    n[:, 2] = np.where(on_cap, 0.0, dz / safe)
    n[:, 1] = np.where(on_cap, np.where(np.abs(p[:, 1] - y1) < np.abs(p[:, 1] - y0), 1.0, -1.0), 0.0)
    ang = np.arctan2(dz, dx)
    u = np.where(on_cap, dx, ang * r)
    v = np.where(on_cap, dz, -p[:, 1])
    return n, u, v


def ellipsoid_t(o, d, c, r):
    r = np.asarray(r, dtype=np.float64)
    oc = (o - np.asarray(c)) / r
    dd = d / r
    a = (dd * dd).sum(axis=1)
    b = (dd * oc).sum(axis=1)
    cc = float((oc * oc).sum()) - 1.0
    disc = b * b - a * cc
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(disc)) / a
    return np.where((disc >= 0) & (t > EPS), t, INF)


def ellipsoid_surface(p, c, r):
    r = np.asarray(r, dtype=np.float64)
    q = (p - np.asarray(c)) / r
    n = q / r
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    rm = float(r.mean())
    u = np.arctan2(q[:, 2], q[:, 0]) * rm
    v = -q[:, 1] * rm
    return n, u, v


INTERSECT = {"box": lambda o, d, inv, p: box_t(o, d, inv, p[0:3], p[3:6]),
             "cylinder": lambda o, d, inv, p: cylinder_t(o, d, *p),
             "ellipsoid": lambda o, d, inv, p: ellipsoid_t(o, d, p[0:3], p[3:6])}
SURFACE = {"box": lambda pt, p: box_surface(pt, p[0:3], p[3:6]),
           "cylinder": lambda pt, p: cylinder_surface(pt, *p),
           "ellipsoid": lambda pt, p: ellipsoid_surface(pt, p[0:3], p[3:6])}
