"""Ray casting of a World: nearest hit per pixel, Lambert shading, class ids, motion mask.

Surfaces are numbered: 0..5 the room faces, then the decals (windows, doors), then the
primitives. Per pixel the nearest surface wins; decals are coplanar with their wall, so they
only replace wall hits inside their rectangle. No shadows and no reflections: a distractor
changes exactly the pixels where it is the nearest hit, which is what the motion mask marks.
"""

import numpy as np

from . import geometry as g
from .camera import pixel_rays
from .classes import CLASS_ID
from .textures import albedo
from .primitives import World
from .world import along_axis

ROOM_CLASS = [CLASS_ID[n] for n in ("wall", "floor", "wall", "wall", "ceiling", "wall")]
DIFFUSE = 0.85


def surface_tables(world: World):
    """Per surface id: class id and whether it moves."""
    cls = ROOM_CLASS + [d.cls for d in world.decals] + [p.cls for p in world.prims]
    dyn = [False] * (6 + len(world.decals)) + [p.dynamic for p in world.prims]
    return np.asarray(cls, dtype=np.uint8), np.asarray(dyn, dtype=bool)


def render_frame(world: World, f: int, include_dynamic: bool = True):
    """Frame ``f`` -> dict rgb uint8 [H, W, 3], classes uint8 [H, W], mask bool [H, W],
    depth float32 [H, W] (z-depth in world units), surface int16 [H, W]."""
    h, w = world.height, world.width
    c2w = world.c2w[f]
    o = c2w[:3, 3].copy()
    d = pixel_rays(c2w, world.k_norm, w, h)
    inv = g._safe_inv(d)

    t, face = g.room_t(o, inv, world.lo, world.hi)
    surf = face.astype(np.int16)
    if world.decals:
        p = o + t[:, None] * d
        for j, dec in enumerate(world.decals):
            a = p[:, along_axis(dec.face)]
            on = (face == dec.face) & (a >= dec.a0) & (a <= dec.a1) & (p[:, 1] >= dec.y0) \
                & (p[:, 1] <= dec.y1)
            surf[on] = 6 + j
    base = 6 + len(world.decals)
    for i, pr in enumerate(world.prims):
        if pr.dynamic and not include_dynamic:
            continue
        params = pr.params[f] if pr.dynamic else pr.params
        ti = g.INTERSECT[pr.shape](o, d, inv, params)
        closer = ti < t
        t = np.where(closer, ti, t)
        surf[closer] = base + i

    p = o + t[:, None] * d
    n = np.empty_like(p)
    alb = np.empty_like(p)
    for sid in np.unique(surf):
        sel = np.nonzero(surf == sid)[0]
        ps = p[sel]
        if sid < 6:
            nn, u, v = g.room_surface(ps, np.full(len(sel), sid))
            mat = world.face_mats[sid]
        elif sid < base:
            dec = world.decals[sid - 6]
            nn, _, _ = g.room_surface(ps, np.full(len(sel), dec.face))
            u = (ps[:, along_axis(dec.face)] - dec.a0) / (dec.a1 - dec.a0)
            v = (dec.y1 - ps[:, 1]) / (dec.y1 - dec.y0)
            mat = dec.mat
        else:
            pr = world.prims[sid - base]
            params = pr.params[f] if pr.dynamic else pr.params
            nn, u, v = g.SURFACE[pr.shape](ps, params)
            mat = pr.mat
        n[sel] = nn
        alb[sel] = albedo(mat, u, v)

    # normals face the camera (a ray grazing a cap edge may land on the far side)
    flip = (n * d).sum(axis=1) > 0
    n[flip] = -n[flip]
    to_l = world.light - p
    dist = np.linalg.norm(to_l, axis=1)
    lam = np.clip((n * to_l).sum(axis=1) / np.maximum(dist, 1e-9), 0, None)
    light = world.ambient + DIFFUSE * lam / (1 + (dist / 4.0) ** 2)
    rgb = np.clip(alb * light[:, None], 0, 1)

    cls_t, dyn_t = surface_tables(world)
    return {"rgb": np.round(rgb * 255).astype(np.uint8).reshape(h, w, 3),
            "classes": cls_t[surf].reshape(h, w),
            "mask": dyn_t[surf].reshape(h, w),
            "depth": t.astype(np.float32).reshape(h, w),
            "surface": surf.reshape(h, w)}
