"""Moving distractors: a "person" (legs, torso, arms: cylinders; head: sphere) and a "pet"
(ellipsoid body, spherical head, cylinder legs). Each walks a straight segment across the
half of the room the cameras look at, one step per frame, so its position changes from frame
to frame while the room stays put. Their primitives are marked dynamic: they make up the
motion mask.
"""

import numpy as np

from .classes import CLASS_ID
from .textures import random_color, random_material
from .primitives import Prim


def _path(rng, world, foot, center, d0, radius, length_rng, n):
    """Start and end (x, z) of a segment whose every frame position keeps ``radius`` clear of
    walls, furniture and cameras and stays on the far side of the room; None if none found."""
    lo, hi = world.lo, world.hi
    cam = world.c2w[:, [0, 2], 3]
    steps = np.linspace(0, 1, max(n, 2) * 3)
    for attempt in range(80):
        length = rng.uniform(*length_rng) * (1 - attempt / 100)
        a = np.array([rng.uniform(lo[0] + radius + 0.2, hi[0] - radius - 0.2),
                      rng.uniform(lo[2] + radius + 0.2, hi[2] - radius - 0.2)])
        ang = rng.uniform(0, 2 * np.pi)
        b = a + length * np.array([np.cos(ang), np.sin(ang)])
        pts = a[None] + steps[:, None] * (b - a)[None]
        if np.any(pts[:, 0] < lo[0] + radius + 0.1) or np.any(pts[:, 0] > hi[0] - radius - 0.1) \
                or np.any(pts[:, 1] < lo[2] + radius + 0.1) or np.any(pts[:, 1] > hi[2] - radius - 0.1):
            continue
        if np.any((pts - center[[0, 2]]) @ d0 > -0.1):
            continue
        if np.min(np.linalg.norm(pts[:, None] - cam[None], axis=2)) < radius + 0.6:
            continue
        if all(foot.free(p[0] - radius, p[0] + radius, p[1] - radius, p[1] + radius,
                         margin=0.02, clear=0.0) for p in pts):
            return a, b
    return None


def moments_along(n):
    """The shoot's moments: n evenly spaced fractions of a mover's path, first to last."""
    return np.linspace(0, 1, n) if n > 1 else np.zeros(1)


def path_positions(m, t):
    """(x, z) of mover ``m`` at the path fractions ``t`` [F]."""
    a, b = m["a"], m["b"]
    return a[None] + np.asarray(t, dtype=np.float64)[:, None] * (b - a)[None]        # [F, 2]


def draw_person(world, rng, foot, center, d0):
    """A person's height, path and clothes (its primitives: person_prims); None if no path fits."""
    h = rng.uniform(1.55, 1.85)
    path = _path(rng, world, foot, center, d0, 0.3, (0.6, 1.8), world.n_frames)
    if path is None:
        return None
    a, b = path
    m = {"class": "person", "height": h, "a": a, "b": b, "radius": 0.3,
         "phase0": rng.uniform(0, 2 * np.pi)}
    m["shirt"] = random_material(rng, ("flat", "stripes", "checker", "noise"), sat=(0.4, 0.9),
                                 val=(0.3, 0.9), period=(0.04, 0.12))
    m["pants"] = random_material(rng, ("flat", "noise"), sat=(0.1, 0.5), val=(0.15, 0.5),
                                 period=(0.05, 0.1))
    m["skin"] = {"kind": "flat", "c0": random_color(rng, (0.3, 0.6), (0.35, 0.9), (0.04, 0.1)),
                 "c1": random_color(rng, (0.3, 0.6), (0.35, 0.9), (0.04, 0.1)), "period": 1.0,
                 "angle": 0.0, "seed": int(rng.integers(0, 2 ** 20))}
    return m


def person_prims(m, t):
    """Person ``m``'s primitives at path fractions ``t`` [F], and its scene.json record."""
    h, a, b = m["height"], m["a"], m["b"]
    pos = path_positions(m, t)
    n = len(pos)
    fwd = (b - a) / max(np.linalg.norm(b - a), 1e-9)
    side = np.array([-fwd[1], fwd[0]])
    # limbs swing with the distance walked (stride about 1 m), legs against arms
    phase = 2 * np.pi * np.linalg.norm(pos - a[None], axis=1) / 1.0 + m["phase0"]
    swing = np.sin(phase)[:, None] * fwd[None]
    cid = CLASS_ID["person"]
    prims = []

    def cyl(name, mat, xz, y0, y1, r):
        p = np.concatenate([xz[:, :1], xz[:, 1:], np.full((n, 1), y0), np.full((n, 1), y1),
                            np.full((n, 1), r)], axis=1)
        prims.append(Prim("cylinder", cid, mat, p, dynamic=True, name=name))

    leg = 0.47 * h
    cyl("person.leg", m["pants"], pos + 0.09 * side + 0.12 * swing, 0.0, leg, 0.065)
    cyl("person.leg", m["pants"], pos - 0.09 * side - 0.12 * swing, 0.0, leg, 0.065)
    cyl("person.torso", m["shirt"], pos, leg - 0.02, 0.82 * h, 0.17)
    cyl("person.arm", m["shirt"], pos + 0.235 * side - 0.1 * swing, 0.5 * h, 0.8 * h, 0.05)
    cyl("person.arm", m["shirt"], pos - 0.235 * side + 0.1 * swing, 0.5 * h, 0.8 * h, 0.05)
    head = np.concatenate([pos[:, :1], np.full((n, 1), 0.9 * h), pos[:, 1:],
                           np.full((n, 3), 0.11)], axis=1)
    prims.append(Prim("ellipsoid", cid, m["skin"], head, dynamic=True, name="person.head"))
    return prims, {"class": "person", "height": h, "start_xz": a.tolist(), "end_xz": b.tolist(),
                   "head_centers": head[:, :3].tolist()}


def draw_pet(world, rng, foot, center, d0):
    """A pet's size, path and fur (its primitives: pet_prims); None if no path fits."""
    s = rng.uniform(0.8, 1.3)
    path = _path(rng, world, foot, center, d0, 0.35 * s, (0.8, 2.4), world.n_frames)
    if path is None:
        return None
    a, b = path
    m = {"class": "pet", "scale": s, "a": a, "b": b, "radius": 0.35 * s}
    m["fur"] = random_material(rng, ("noise", "flat", "stripes"), sat=(0.2, 0.8), val=(0.2, 0.85),
                               period=(0.03, 0.08), hue=(0.02, 0.12))
    return m


def pet_prims(m, t):
    """Pet ``m``'s primitives at path fractions ``t`` [F], and its scene.json record."""
    s, a, b, fur = m["scale"], m["a"], m["b"], m["fur"]
    pos = path_positions(m, t)
    n = len(pos)
    d = b - a
    # axis-aligned shapes: the body stretches along the dominant walking axis
    ax = 0 if abs(d[0]) >= abs(d[1]) else 1
    fwd = np.zeros(2)
    fwd[ax] = np.sign(d[ax]) or 1.0
    side = np.array([-fwd[1], fwd[0]])
    cid = CLASS_ID["pet"]
    semi = np.array([0.14, 0.12, 0.14]) * s
    semi[0 if ax == 0 else 2] = 0.3 * s
    body = np.concatenate([pos[:, :1], np.full((n, 1), 0.3 * s), pos[:, 1:],
                           np.tile(semi, (n, 1))], axis=1)
    hp = pos + 0.32 * s * fwd[None]
    head = np.concatenate([hp[:, :1], np.full((n, 1), 0.42 * s), hp[:, 1:],
                           np.full((n, 3), 0.1 * s)], axis=1)
    prims = [Prim("ellipsoid", cid, fur, body, dynamic=True, name="pet.body"),
             Prim("ellipsoid", cid, fur, head, dynamic=True, name="pet.head")]
    gait = np.sin(2 * np.pi * np.linalg.norm(pos - a[None], axis=1) / 0.5)[:, None] * fwd[None]
    for i, (fa, sa) in enumerate(((0.18, 0.08), (0.18, -0.08), (-0.18, 0.08), (-0.18, -0.08))):
        sign = 1 if i in (0, 3) else -1
        xz = pos + s * (fa * fwd[None] + sa * side[None]) + 0.04 * s * sign * gait
        p = np.concatenate([xz[:, :1], xz[:, 1:], np.zeros((n, 1)), np.full((n, 1), 0.22 * s),
                            np.full((n, 1), 0.03 * s)], axis=1)
        prims.append(Prim("cylinder", cid, fur, p, dynamic=True, name="pet.leg"))
    return prims, {"class": "pet", "scale": s, "start_xz": a.tolist(), "end_xz": b.tolist(),
                   "body_centers": body[:, :3].tolist()}


MOVER_PRIMS = {"person": person_prims, "pet": pet_prims}


def place_movers(world, t):
    """Puts every mover of ``world.movers`` at path fractions ``t`` (one per frame): their
    primitives join ``world.prims``, their records ``world.distractors``."""
    for m in world.movers:
        prims, record = MOVER_PRIMS[m["class"]](m, t)
        world.prims.extend(prims)
        world.distractors.append(record)


def draw_movers(world, rng, foot, center, d0):
    """A person (probability 0.85) and a pet (0.6), at least one of them, into ``world.movers``
    (parameters only: place_movers puts them into frames)."""
    want_person = rng.uniform() < 0.85
    want_pet = rng.uniform() < 0.6 or not want_person
    if want_person:
        m = draw_person(world, rng, foot, center, d0)
        if m:
            world.movers.append(m)
    if want_pet:
        m = draw_pet(world, rng, foot, center, d0)
        if m:
            world.movers.append(m)
