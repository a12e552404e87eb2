"""Procedural textures: albedo as a function of surface coordinates (u, v).

Each surface carries a material dict; ``shade_albedo`` evaluates it for many points at once.
Coordinates are metres on the surface (so stripes keep their width whatever the object's
size) except for windows and doors, whose (u, v) run over [0, 1] across the rectangle.
Textures matter for SPAR: without texture, pose estimation and photometric losses have
nothing to lock onto.
"""

import numpy as np

KINDS = ("flat", "stripes", "checker", "noise", "gradient")


def _hash2(ix: np.ndarray, iy: np.ndarray, seed: int) -> np.ndarray:
    """Integer lattice -> [0, 1): a fixed integer hash (wrapping uint32 arithmetic), so the
    noise is the same on every machine and independent of numpy's generators."""
    h = (ix.astype(np.int64) * 374761393 + iy.astype(np.int64) * 668265263
         + seed * 2147483647) & 0xFFFFFFFF
    h = ((h ^ (h >> 13)) * 1274126177) & 0xFFFFFFFF
    h = h ^ (h >> 16)
    return (h & 0xFFFFFF).astype(np.float64) / float(0x1000000)


def value_noise(u: np.ndarray, v: np.ndarray, seed: int) -> np.ndarray:
    """Smooth value noise in [0, 1]: hashed lattice values, smoothstep-bilinear blend."""
    iu, iv = np.floor(u), np.floor(v)
    fu, fv = u - iu, v - iv
    fu = fu * fu * (3 - 2 * fu)
    fv = fv * fv * (3 - 2 * fv)
    a = _hash2(iu, iv, seed)
    b = _hash2(iu + 1, iv, seed)
    c = _hash2(iu, iv + 1, seed)
    d = _hash2(iu + 1, iv + 1, seed)
    return (a * (1 - fu) + b * fu) * (1 - fv) + (c * (1 - fu) + d * fu) * fv


def fbm(u: np.ndarray, v: np.ndarray, seed: int, octaves: int = 3) -> np.ndarray:
    acc, amp, norm = 0.0, 1.0, 0.0
    for o in range(octaves):
        acc = acc + amp * value_noise(u * (2 ** o), v * (2 ** o), seed + 101 * o)
        norm += amp
        amp *= 0.5
    return acc / norm


def random_color(rng: np.random.Generator, sat=(0.2, 0.7), val=(0.4, 0.95),
                 hue=(0.0, 1.0)) -> np.ndarray:
    """An RGB colour in [0, 1] from hue / saturation / value ranges (HSV -> RGB)."""
    h = rng.uniform(*hue) % 1.0
    s = rng.uniform(*sat)
    v = rng.uniform(*val)
    k = (np.array([5.0, 3.0, 1.0]) + h * 6) % 6
    return v - v * s * np.clip(np.minimum(k, 4 - k), 0, 1)


def random_material(rng: np.random.Generator, kinds=KINDS, sat=(0.2, 0.7), val=(0.4, 0.95),
                    contrast=(0.15, 0.45), period=(0.1, 0.5), hue=(0.0, 1.0)) -> dict:
    """A material: kind, two colours (the second a lighter or darker shade of the first, or
    another hue), period in metres, direction, noise seed."""
    c0 = random_color(rng, sat, val, hue)
    if rng.uniform() < 0.5:
        c1 = np.clip(c0 * (1 + rng.choice([-1, 1]) * rng.uniform(*contrast)), 0, 1)
    else:
        c1 = random_color(rng, sat, val, hue)
    return {"kind": str(rng.choice(kinds)), "c0": c0, "c1": c1,
            "period": float(rng.uniform(*period)), "angle": float(rng.uniform(0, np.pi)),
            "seed": int(rng.integers(0, 2 ** 20))}


def _weight(mat: dict, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Blend weight in [0, 1] between c0 and c1."""
    kind, p = mat["kind"], mat["period"]
    if kind == "flat":
        return 0.25 * fbm(u / 0.05, v / 0.05, mat["seed"], 2)  # faint grain, never empty
    if kind == "stripes":
        s = (u * np.cos(mat["angle"]) + v * np.sin(mat["angle"])) / p
        return np.floor(s) % 2
    if kind == "checker":
        return (np.floor(u / p) + np.floor(v / p)) % 2
    if kind == "noise":
        return fbm(u / p, v / p, mat["seed"])
    if kind == "gradient":
        s = (u * np.cos(mat["angle"]) + v * np.sin(mat["angle"])) / (4 * p)
        return 0.5 + 0.5 * np.sin(2 * np.pi * s)
    if kind == "window":
        return _window(u, v)
    if kind == "door":
        return _door(u, v)
    raise ValueError(f"unknown texture kind {kind}")


def _window(u, v):
    # frame and a cross of mullions in c1, panes in c0 (sky colour, lighter towards the top:
    # v grows downwards on walls, see geometry.room_surface)
    frame = (u < 0.07) | (u > 0.93) | (v < 0.07) | (v > 0.93) | (np.abs(u - 0.5) < 0.025) \
        | (np.abs(v - 0.45) < 0.025)
    sky = 0.35 * v
    return np.where(frame, 1.0, sky)


def _door(u, v):
    # panel in c0 with two inset rectangles and a knob in c1
    inset = ((np.abs(u - 0.5) < 0.32) & (((v > 0.08) & (v < 0.42)) | ((v > 0.52) & (v < 0.92))))
    edge = inset & ~((np.abs(u - 0.5) < 0.29) & (((v > 0.10) & (v < 0.40)) | ((v > 0.54) & (v < 0.90))))
    knob = (u - 0.86) ** 2 + ((v - 0.5) * 2.2) ** 2 < 0.05 ** 2
    return np.where(knob, 1.0, np.where(edge, 0.6, 0.0))


def albedo(mat: dict, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """[N] coordinates -> [N, 3] albedo in [0, 1]."""
    w = _weight(mat, u, v)[:, None]
    return mat["c0"][None, :] * (1 - w) + mat["c1"][None, :] * w
