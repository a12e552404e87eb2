"""A random room from a seed: box room, materials, windows and doors, furniture, camera
path, and (optionally) moving distractors.

Three independent random streams, numpy.random.default_rng([seed, stream]):
  0 room (size, materials, decals, furniture, light), 1 cameras, 2 distractors.
So the static version of a scene (no distractors) has the very same room and cameras, and
a clean background for every frame of its dynamic version.

Takes (``reshoot``): take k >= 1 of a seed is the same room, furniture and movers as its
8-frame shoot (take 0, what ``spar-scenes`` writes), seen from another camera arc on the same
side of the room and at other moments of the movers' walks (streams [seed, 1, k] and
[seed, 2, k]): what a model fitted to a few rooms trains on without ever seeing their frames.

World axes: y up, floor at y = 0, room x in [0, W], z in [0, D]. Room faces are numbered as
geometry.room_t returns them: 0 -x, 1 floor, 2 -z, 3 +x, 4 ceiling, 5 +z.
"""

import dataclasses
from typing import List

import numpy as np

from . import camera
from .classes import CLASS_ID
from .distractors import draw_movers, moments_along, path_positions, place_movers
from .primitives import Decal, Prim, World
from .textures import random_color, random_material

WALL_FACES = (0, 2, 3, 5)
# outward normal of each wall in the (x, z) plane
WALL_OUT = {0: (-1.0, 0.0), 3: (1.0, 0.0), 2: (0.0, -1.0), 5: (0.0, 1.0)}


def along_axis(face: int) -> int:
    """World axis that runs along a wall: z for the x-walls, x for the z-walls."""
    return 2 if face in (0, 3) else 0


def wall_box(lo, hi, face, a0, a1, b0, b1, y0, y1):
    """Axis-aligned box in wall-local terms: along-wall [a0, a1], distance from the wall
    [b0, b1], heights [y0, y1] -> (lo[3], hi[3])."""
    if face in (0, 3):
        x = (lo[0] + b0, lo[0] + b1) if face == 0 else (hi[0] - b1, hi[0] - b0)
        return np.array([x[0], y0, a0]), np.array([x[1], y1, a1])
    z = (lo[2] + b0, lo[2] + b1) if face == 2 else (hi[2] - b1, hi[2] - b0)
    return np.array([a0, y0, z[0]]), np.array([a1, y1, z[1]])


class _Footprints:
    """Occupied (x, z) rectangles, so furniture does not interpenetrate."""

    def __init__(self, keep_clear):
        self.rects = []
        self.keep_clear = keep_clear      # [M, 2] points (camera positions) to stay away from

    def free(self, x0, x1, z0, z1, margin=0.08, clear=0.45) -> bool:
        for (a0, a1, b0, b1) in self.rects:
            if x0 < a1 + margin and a0 < x1 + margin and z0 < b1 + margin and b0 < z1 + margin:
                return False
        px = np.clip(self.keep_clear[:, 0], x0, x1)
        pz = np.clip(self.keep_clear[:, 1], z0, z1)
        d = np.hypot(self.keep_clear[:, 0] - px, self.keep_clear[:, 1] - pz)
        return bool(np.all(d > clear))

    def add(self, x0, x1, z0, z1):
        self.rects.append((x0, x1, z0, z1))


def build_world(seed: int, n_frames: int, width: int, height: int,
                distractors: bool = True) -> World:
    rng = np.random.default_rng([seed, 0])
    rng_cam = np.random.default_rng([seed, 1])
    rng_dyn = np.random.default_rng([seed, 2])

    size = np.array([rng.uniform(4.0, 6.0), rng.uniform(2.5, 3.0), rng.uniform(4.0, 6.0)])
    lo, hi = np.zeros(3), size
    center = size / 2

    # ---- cameras: an arc on one side of the room, looking across it
    phi0 = rng_cam.uniform(0, 2 * np.pi)
    d0 = np.array([np.cos(phi0), np.sin(phi0)])          # centre -> cameras, in (x, z)
    # as far back as leaves 0.8 m to the walls, so the far half of the room fills the view
    radius = rng_cam.uniform(0.6, max(0.7, min(center[0], center[2]) - 0.8))
    cam_h = rng_cam.uniform(1.3, 1.7)
    half_arc = rng_cam.uniform(0.15, 0.35)
    reach = rng_cam.uniform(1.0, 1.8)
    target = np.array([center[0] - reach * d0[0], rng_cam.uniform(0.9, 1.3),
                       center[2] - reach * d0[1]])
    c2w = camera.trajectory(rng_cam, center, n_frames, radius, cam_h, phi0, half_arc, target)
    k_norm = camera.intrinsics(rng_cam.uniform(0.6, 0.85), width, height)
    cam_xz = c2w[:, [0, 2], 3]

    # walls the cameras can see: all but the one behind them
    behind = max(WALL_FACES, key=lambda f: np.dot(WALL_OUT[f], d0))
    visible = [f for f in WALL_FACES if f != behind]
    far = min(WALL_FACES, key=lambda f: np.dot(WALL_OUT[f], d0))
    # the far wall is seen in every frame: it gets half of the placements
    wall_p = [0.5 if f == far else 0.25 for f in visible]

    def along_range(f, w):
        """Where along wall f an item of width w may start: on the side walls only the
        half the cameras look at (plus a little), so that most things are in view."""
        ax = along_axis(f)
        a_lo, a_hi = lo[ax] + 0.1, hi[ax] - 0.1 - w
        d_ax = d0[0] if ax == 0 else d0[1]
        if d_ax > 0.5:
            a_hi = min(a_hi, center[ax] + 0.3)
        elif d_ax < -0.5:
            a_lo = max(a_lo, center[ax] - 0.3 - w)
        return a_lo, a_hi

    # ---- materials of the room
    wall_mat = random_material(rng, ("flat", "stripes", "gradient", "noise", "checker"),
                               sat=(0.05, 0.35), val=(0.6, 0.95), period=(0.15, 0.6))
    face_mats = [wall_mat] * 6
    if rng.uniform() < 0.4:   # an accent wall
        accent = int(rng.choice(visible))
        face_mats = list(face_mats)
        face_mats[accent] = random_material(rng, sat=(0.2, 0.6), val=(0.45, 0.9))
    face_mats = list(face_mats)
    face_mats[1] = random_material(rng, ("stripes", "checker", "noise"), sat=(0.2, 0.6),
                                   val=(0.3, 0.8), period=(0.15, 0.6))
    face_mats[4] = random_material(rng, ("flat", "noise"), sat=(0.0, 0.1), val=(0.85, 1.0),
                                   period=(0.3, 1.0))

    # ---- windows and a door on visible walls
    decals: List[Decal] = []
    spans = {f: [] for f in WALL_FACES}

    def place_decal(cls, width_rng, y0_rng, h_rng, mat):
        for _ in range(30):
            f = int(rng.choice(visible, p=wall_p))
            w = rng.uniform(*width_rng)
            a_lo, a_hi = along_range(f, w)
            if a_hi - a_lo < 0.4:
                continue
            a0 = rng.uniform(a_lo + 0.2, a_hi - 0.2)
            if any(a0 < s1 + 0.2 and s0 < a0 + w + 0.2 for s0, s1 in spans[f]):
                continue
            y0 = rng.uniform(*y0_rng)
            y1 = min(y0 + rng.uniform(*h_rng), size[1] - 0.15)
            spans[f].append((a0, a0 + w))
            decals.append(Decal(f, CLASS_ID[cls], mat, a0, a0 + w, y0, y1))
            return decals[-1]
        return None

    door = place_decal("door", (0.8, 1.0), (0.0, 0.0), (2.0, 2.2),
                       {"kind": "door", "c0": random_color(rng, (0.3, 0.7), (0.3, 0.8), (0.03, 0.12)),
                        "c1": random_color(rng, (0.0, 0.3), (0.1, 0.3)), "period": 1.0,
                        "angle": 0.0, "seed": 0})
    for _ in range(int(rng.integers(1, 3))):
        place_decal("window", (0.8, 1.6), (0.8, 1.1), (0.8, 1.2),
                    {"kind": "window", "c0": random_color(rng, (0.2, 0.5), (0.85, 1.0), (0.5, 0.6)),
                     "c1": random_color(rng, (0.0, 0.15), (0.8, 1.0)), "period": 1.0,
                     "angle": 0.0, "seed": 0})

    # ---- furniture along the visible walls
    prims: List[Prim] = []
    objects: List[dict] = []
    foot = _Footprints(cam_xz)

    def place_along_wall(w, depth, gap_rng, avoid_door=True):
        """(face, a0, b0, footprint) of a free spot, or None."""
        for _ in range(40):
            f = int(rng.choice(visible, p=wall_p))
            a_lo, a_hi = along_range(f, w)
            if a_hi < a_lo:
                continue
            a0 = rng.uniform(a_lo, a_hi)
            if avoid_door and door is not None and door.face == f and \
                    a0 < door.a1 + 0.2 and door.a0 < a0 + w + 0.2:
                continue
            b0 = rng.uniform(*gap_rng)
            blo, bhi = wall_box(lo, hi, f, a0, a0 + w, b0, b0 + depth, 0, 1)
            fp = (blo[0], bhi[0], blo[2], bhi[2])
            if foot.free(*fp):
                foot.add(*fp)
                return f, a0, b0
        return None

    def add_box(cls, mat, name, blo, bhi):
        prims.append(Prim("box", CLASS_ID[cls], mat, np.concatenate([blo, bhi]), name=name))

    # sofa: seat, back against the wall, two armrests
    w, dep = rng.uniform(1.4, 2.0), rng.uniform(0.8, 0.95)
    spot = place_along_wall(w, dep, (0.02, 0.1))
    if spot:
        f, a0, b0 = spot
        mat = random_material(rng, ("flat", "noise", "stripes", "checker"), sat=(0.3, 0.8),
                              val=(0.3, 0.85), period=(0.05, 0.25))
        seat_h, back_h, arm_h = rng.uniform(0.38, 0.46), rng.uniform(0.75, 0.95), rng.uniform(0.55, 0.65)
        add_box("sofa", mat, "sofa.seat", *wall_box(lo, hi, f, a0, a0 + w, b0, b0 + dep, 0, seat_h))
        add_box("sofa", mat, "sofa.back", *wall_box(lo, hi, f, a0, a0 + w, b0, b0 + 0.22, 0, back_h))
        add_box("sofa", mat, "sofa.arm", *wall_box(lo, hi, f, a0, a0 + 0.16, b0, b0 + dep, 0, arm_h))
        add_box("sofa", mat, "sofa.arm", *wall_box(lo, hi, f, a0 + w - 0.16, a0 + w, b0, b0 + dep, 0, arm_h))
        objects.append({"class": "sofa", "wall": f, "along": [a0, a0 + w], "from_wall": [b0, b0 + dep]})

    # tables: rectangular (top + 4 legs) or round (top, stem, base)
    for _ in range(int(rng.integers(1, 3))):
        round_top = rng.uniform() < 0.4
        w = rng.uniform(0.7, 1.0) if round_top else rng.uniform(0.8, 1.4)
        dep = w if round_top else rng.uniform(0.6, 0.9)
        spot = place_along_wall(w, dep, (0.1, 0.9))
        if not spot:
            continue
        f, a0, b0 = spot
        mat = random_material(rng, ("stripes", "flat", "noise"), sat=(0.2, 0.7), val=(0.25, 0.8),
                              period=(0.03, 0.12), hue=(0.02, 0.14))
        top_y = rng.uniform(0.68, 0.78)
        blo, bhi = wall_box(lo, hi, f, a0, a0 + w, b0, b0 + dep, 0, top_y)
        if round_top:
            cx, cz, r = (blo[0] + bhi[0]) / 2, (blo[2] + bhi[2]) / 2, w / 2
            for (r_, y0, y1, nm) in ((r, top_y - 0.04, top_y, "table.top"),
                                      (0.05, 0.04, top_y - 0.04, "table.stem"),
                                      (0.25 * w, 0.0, 0.04, "table.base")):
                prims.append(Prim("cylinder", CLASS_ID["table"], mat,
                                  np.array([cx, cz, y0, y1, r_]), name=nm))
        else:
            add_box("table", mat, "table.top", np.array([blo[0], top_y - 0.05, blo[2]]), bhi)
            for lx in (blo[0] + 0.03, bhi[0] - 0.09):
                for lz in (blo[2] + 0.03, bhi[2] - 0.09):
                    add_box("table", mat, "table.leg", np.array([lx, 0.0, lz]),
                            np.array([lx + 0.06, top_y - 0.05, lz + 0.06]))
        objects.append({"class": "table", "round": bool(round_top), "wall": f,
                        "along": [a0, a0 + w], "from_wall": [b0, b0 + dep]})

    # plants: a pot and one or two leafy ellipsoids
    for _ in range(int(rng.integers(1, 3))):
        pr = rng.uniform(0.14, 0.24)
        spot = place_along_wall(2 * pr, 2 * pr, (0.05, 0.3), avoid_door=True)
        if not spot:
            continue
        f, a0, b0 = spot
        blo, bhi = wall_box(lo, hi, f, a0, a0 + 2 * pr, b0, b0 + 2 * pr, 0, 1)
        cx, cz = (blo[0] + bhi[0]) / 2, (blo[2] + bhi[2]) / 2
        pot_h = rng.uniform(0.3, 0.5)
        pot = random_material(rng, ("flat", "stripes"), sat=(0.4, 0.8), val=(0.4, 0.8),
                              period=(0.04, 0.1), hue=(0.0, 0.1))
        leaf = random_material(rng, ("noise",), sat=(0.4, 0.85), val=(0.25, 0.7),
                               period=(0.04, 0.12), hue=(0.22, 0.42))
        prims.append(Prim("cylinder", CLASS_ID["plant"], pot, np.array([cx, cz, 0.0, pot_h, pr]),
                          name="plant.pot"))
        fr = rng.uniform(1.3, 2.0) * pr
        fh = rng.uniform(1.0, 2.0) * fr
        prims.append(Prim("ellipsoid", CLASS_ID["plant"], leaf,
                          np.array([cx, pot_h + fh * 0.8, cz, fr, fh, fr]), name="plant.leaves"))
        objects.append({"class": "plant", "wall": f, "center_xz": [cx, cz], "pot_radius": pr})

    light = np.array([center[0] + rng.uniform(-1, 1), size[1] - 0.15, center[2] + rng.uniform(-1, 1)])
    ambient = rng.uniform(0.3, 0.45)

    world = World(seed, width, height, n_frames, lo, hi, face_mats, decals, prims, light,
                  ambient, c2w, k_norm, objects, footprints=list(foot.rects),
                  arc={"center": center, "phi0": phi0, "radius": radius, "height": cam_h,
                       "half_arc": half_arc, "target": target})
    # distractors: drawn after everything static, from their own stream
    if distractors:
        draw_movers(world, rng_dyn, foot, center, d0)
        place_movers(world, moments_along(n_frames))
    return world


# A room is defined by its 8-frame shoot (take 0, the length of the shipped scenes): the
# furniture keeps clear of those cameras, the movers' paths too.
TAKE_ROOM_FRAMES = 8


def _arc_is_clear(world, c2w, mover_xz) -> bool:
    """Every camera inside the room, 0.45 m from the furniture's footprints and 0.5 m beyond
    each mover's radius at every frame of the take."""
    xz = c2w[:, [0, 2], 3]
    lo, hi = world.lo[[0, 2]] + 0.3, world.hi[[0, 2]] - 0.3
    if np.any(xz < lo) or np.any(xz > hi):
        return False
    for (x0, x1, z0, z1) in world.footprints:
        d = np.hypot(xz[:, 0] - np.clip(xz[:, 0], x0, x1), xz[:, 1] - np.clip(xz[:, 1], z0, z1))
        if np.any(d <= 0.45):
            return False
    for m, pos in mover_xz:
        if np.min(np.linalg.norm(xz[:, None] - pos[None], axis=2)) <= m["radius"] + 0.5:
            return False
    return True


def reshoot(world: World, take: int, n_frames: int, distractors: bool = True) -> World:
    """Take ``take`` (>= 1) of ``world`` (built with its movers drawn, i.e. distractors=True):
    the same room, furniture and movers over ``n_frames`` frames of another camera arc (its
    angle within 0.4 rad of the shoot's, its radius, height, span, aim and focal length drawn
    anew; the shoot's own arc with fresh jitter if 100 draws find none clear of furniture and
    movers) and at other moments of the movers' walks (a stretch of at least a quarter of each
    path, either way). ``distractors=False``: the same take without the movers."""
    if take < 1:
        raise ValueError("take must be >= 1 (take 0 is the scene itself)")
    rng_t = np.random.default_rng([world.seed, 2, take])
    u0 = rng_t.uniform(0.0, 0.75)
    u1 = rng_t.uniform(u0 + 0.25, 1.0)
    t = np.linspace(u0, u1, n_frames) if n_frames > 1 else np.full(1, u0)
    if rng_t.uniform() < 0.5:
        t = t[::-1].copy()
    mover_xz = [(m, path_positions(m, t)) for m in world.movers]

    rng = np.random.default_rng([world.seed, 1, take])
    arc = world.arc
    center = arc["center"]
    c2w = None
    for _ in range(100):
        phi = arc["phi0"] + rng.uniform(-0.4, 0.4)
        d = np.array([np.cos(phi), np.sin(phi)])
        radius = rng.uniform(0.6, max(0.7, min(center[0], center[2]) - 0.8))
        height = rng.uniform(1.2, 1.8)
        half_arc = rng.uniform(0.1, 0.4)
        reach = rng.uniform(1.0, 1.8)
        target = np.array([center[0] - reach * d[0], rng.uniform(0.9, 1.3), center[2] - reach * d[1]])
        cand = camera.trajectory(rng, center, n_frames, radius, height, phi, half_arc, target)
        if _arc_is_clear(world, cand, mover_xz):
            c2w = cand
            break
    if c2w is None:
        c2w = camera.trajectory(rng, center, n_frames, arc["radius"], arc["height"], arc["phi0"],
                                arc["half_arc"], arc["target"])
    k_norm = camera.intrinsics(rng.uniform(0.6, 0.85), world.width, world.height)
    shot = dataclasses.replace(world, n_frames=n_frames, c2w=c2w, k_norm=k_norm,
                               prims=[p for p in world.prims if not p.dynamic], distractors=[],
                               movers=list(world.movers) if distractors else [])
    if distractors:
        place_movers(shot, t)
    return shot
