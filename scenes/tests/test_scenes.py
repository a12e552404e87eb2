#!/usr/bin/python3
"""Tests of the procedural scene generator ``spar_scenes`` and its tool ``scenes/spar-scenes``.

Small images (48-96 px, 3-5 frames) keep the file to a few seconds. The tool runs as a
subprocess where it writes scenes; its refusals go through spar_scenes.cli.main in this process.
Run: cd /work/main && PYTHONPATH=converter /usr/bin/python3 -m pytest -q scenes/tests/test_scenes.py
"""

import io
import json
import os
import subprocess
import sys
from contextlib import redirect_stderr, redirect_stdout

import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))

from spar_scenes import CLASS_ID, CLASS_NAMES, copy_paste, generate_scene, split_seeds  # noqa: E402
from spar_scenes.camera import project  # noqa: E402
from spar_scenes.render import render_frame  # noqa: E402
from spar_scenes.primitives import Prim  # noqa: E402
from spar_scenes.world import build_world  # noqa: E402
from spar_scenes.generate import shift  # noqa: E402

TOOL = os.path.join(HERE, "..", "spar-scenes")
ARRAYS = ("rgb", "classes", "mask", "depth", "c2w", "c2w_canonical", "fxfycxcy")
DYN = [CLASS_ID["person"], CLASS_ID["pet"]]


def run(*args):
    return subprocess.run([sys.executable, TOOL] + [str(a) for a in args], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True, timeout=120)


def run_in_process(*args):
    """spar_scenes.cli.main(ARGS) here: (exit code, stderr) as the subprocess gives them."""
    from spar_scenes.cli import main
    err = io.StringIO()
    with redirect_stdout(io.StringIO()), redirect_stderr(err):
        try:
            code = main([str(a) for a in args])
        except SystemExit as e:     # argparse's usage errors
            code = e.code
    return code, err.getvalue()


def dynamic_seed(n_frames=4, size=64):
    """The first seed whose scene shows a distractor (most do)."""
    for s in range(20):
        sc = generate_scene(s, n_frames, size)
        if sc["mask"].any():
            return s, sc
    raise AssertionError("no scene among 20 shows a distractor")


# ----------------------------------------------------------------------------- API
def test_same_seed_same_bytes():
    a = generate_scene(11, 4, 48)
    b = generate_scene(11, 4, 48)
    for k in ARRAYS:
        assert a[k].dtype == b[k].dtype and a[k].tobytes() == b[k].tobytes(), k
    assert json.dumps(a["info"]) == json.dumps(b["info"])


SHIPPED = os.path.join(HERE, "..", "..", "data", "scenes")


def test_shipped_scenes_are_take_0_of_their_seeds():
    """The repository's demo scenes are what the generator makes of their seeds: the rooms a
    model fitted to them (spar-train --fit-scenes) trains on are these rooms."""
    from PIL import Image
    with open(os.path.join(SHIPPED, "index.json")) as f:
        index = json.load(f)
    assert len(index["scenes"]) == 3
    for sc in index["scenes"]:
        world = build_world(sc["seed"], index["frames"], index["width"], index["height"], distractors=True)
        for i in (0, index["frames"] - 1):                  # the arc's ends, the movers' too
            png = np.asarray(Image.open(os.path.join(SHIPPED, sc["path"], "rgb_%02d.png" % i)).convert("RGB"))
            assert np.array_equal(png, render_frame(world, i)["rgb"]), (sc["seed"], i)


def _static_prims(scene):
    return [(p.shape, p.cls, repr(sorted(p.mat.items())), p.params.tobytes())
            for p in scene["_world"].prims if not p.dynamic]


def test_takes_keep_the_room_and_move_cameras_and_movers():
    """Take k >= 1: the same room (walls, decals, furniture, light) and movers (paths,
    clothes), another camera arc, other moments of the walks; its static version has its
    cameras; the same take twice is the same bytes."""
    seed = 1000002                                          # a person and a pet
    shoot = generate_scene(seed, 8, 48)
    w0 = shoot["_world"]
    for take in (1, 2):
        t = generate_scene(seed, 5, 48, take=take)
        w = t["_world"]
        assert t["take"] == take and t["rgb"].shape == (5, 48, 48, 3)
        assert _static_prims(t) == _static_prims(shoot)
        assert repr(w.decals) == repr(w0.decals) and repr(w.face_mats) == repr(w0.face_mats)
        assert np.array_equal(w.light, w0.light) and np.array_equal(w.hi, w0.hi)
        assert [m["class"] for m in w.movers] == [m["class"] for m in w0.movers] == ["person", "pet"]
        for m, m0 in zip(w.movers, w0.movers):
            assert np.array_equal(m["a"], m0["a"]) and np.array_equal(m["b"], m0["b"])
        # every camera of the take is at least 5 cm from every camera of the shoot
        d = np.linalg.norm(t["c2w"][:, None, :3, 3] - shoot["c2w"][None, :, :3, 3], axis=2)
        assert d.min() > 0.05, d.min()
        # the movers stand elsewhere than in any frame of the shoot
        heads = np.array(w.distractors[0]["head_centers"])
        heads0 = np.array(w0.distractors[0]["head_centers"])
        assert np.linalg.norm(heads[:, None] - heads0[None], axis=2).min() > 1e-3
        assert t["mask"].any()
        static = generate_scene(seed, 5, 48, distractors=False, take=take)
        assert np.array_equal(static["c2w"], t["c2w"]) and not static["mask"].any()
        again = generate_scene(seed, 5, 48, take=take)
        for k in ARRAYS:
            assert again[k].tobytes() == t[k].tobytes(), k
    assert not np.allclose(generate_scene(seed, 5, 48, take=1)["c2w"], generate_scene(seed, 5, 48, take=2)["c2w"])
    with pytest.raises(ValueError):
        generate_scene(seed, 5, 48, take=-1)


def test_different_seeds_differ():
    a, b = generate_scene(1, 3, 48), generate_scene(2, 3, 48)
    assert not np.array_equal(a["rgb"], b["rgb"])
    assert not np.allclose(a["c2w"], b["c2w"])


def test_shapes_types_and_sizes():
    s = generate_scene(5, 3, (40, 72))                     # (height, width)
    assert s["rgb"].shape == (3, 40, 72, 3) and s["rgb"].dtype == np.uint8
    assert s["classes"].shape == (3, 40, 72) and s["classes"].dtype == np.uint8
    assert s["mask"].dtype == bool and s["depth"].dtype == np.float32
    assert s["c2w"].shape == (3, 4, 4) and s["fxfycxcy"].shape == (3, 4)
    assert np.all(s["depth"] > 0) and np.all(np.isfinite(s["depth"]))
    assert s["classes"].max() < len(CLASS_NAMES)
    # square pixels: the same pixel focal on both axes; principal point at the centre
    fx, fy, cx, cy = s["fxfycxcy"][0]
    assert abs(fx * 72 - fy * 40) < 1e-9 and cx == 0.5 and cy == 0.5
    one = generate_scene(5, 1, 16)
    assert one["rgb"].shape == (1, 16, 16, 3)
    with pytest.raises(ValueError):
        generate_scene(5, 0, 16)


def test_class_maps_contain_the_named_classes():
    seen = set()
    for seed in range(8):
        s = generate_scene(seed, 3, 48)
        ids = set(np.unique(s["classes"]).tolist())
        assert {CLASS_ID["wall"], CLASS_ID["floor"]} <= ids, seed
        seen |= ids
    assert seen == set(range(len(CLASS_NAMES))), [CLASS_NAMES[i] for i in set(range(10)) - seen]


def test_motion_mask_is_where_a_distractor_is_nearest():
    seed, dyn = dynamic_seed()
    static = generate_scene(seed, 4, 64, distractors=False)
    # an independent re-render without distractors: the room and cameras are the same ...
    assert np.array_equal(dyn["c2w"], static["c2w"])
    # ... and the pixels that change are exactly the mask
    changed = (dyn["rgb"] != static["rgb"]).any(axis=3) | (dyn["classes"] != static["classes"]) \
        | (dyn["depth"] != static["depth"])
    assert np.array_equal(changed, dyn["mask"])
    assert np.all(dyn["depth"][dyn["mask"]] < static["depth"][dyn["mask"]])
    assert np.array_equal(np.isin(dyn["classes"], DYN), dyn["mask"])
    assert np.array_equal(dyn["has_distractors"], dyn["mask"].any(axis=(1, 2)))


def test_distractors_move_between_frames():
    seed, s = dynamic_seed()
    d = s["info"]["distractors"][0]
    centers = np.array(d.get("head_centers") or d.get("body_centers"))
    steps = np.linalg.norm(np.diff(centers, axis=0), axis=1)
    assert np.all(steps > 0.05)


def test_static_scenes_have_empty_masks():
    for seed in range(3):
        s = generate_scene(seed, 3, 48, distractors=False)
        assert not s["mask"].any() and not s["has_distractors"].any()
        assert not np.isin(s["classes"], DYN).any()
        assert s["kind"] == "static" and s["info"]["distractors"] == []


def test_camera_convention_projects_onto_the_rendered_pixel():
    """Put small spheres at known camera-frame positions, render, and check that projecting
    their centres with the returned c2w / normalized intrinsics lands on pixels the sphere
    covers, and that SPAR's own Plücker ray of that pixel points at the sphere."""
    h, w, f = 48, 80, 1                                    # non-square: catches W/H swaps
    world = build_world(4, 3, w, h, distractors=False)
    c2w, k = world.c2w[f], world.k_norm
    # (right, down, forward) in metres: x > 0 must land right of centre, y > 0 below it
    spots = [(0.0, 0.0, 1.0), (0.25, 0.1, 1.2), (-0.3, -0.12, 1.1), (0.2, -0.15, 0.9)]
    base = len(world.prims)
    for x, y, z in spots:
        center = c2w[:3, :3] @ np.array([x, y, z]) + c2w[:3, 3]
        world.prims.append(Prim("ellipsoid", CLASS_ID["plant"], {"kind": "flat", "c0": np.ones(3),
                                "c1": np.ones(3), "period": 1.0, "angle": 0.0, "seed": 0},
                                np.concatenate([center, [0.03] * 3])))
    out = render_frame(world, f)
    surface_base = 6 + len(world.decals) + base
    import torch
    from spar_reference.spar import plucker_rays
    rays = plucker_rays(torch.tensor(c2w[None]), torch.tensor(k[None]), h, w)[0, 3:].numpy()
    for i, (x, y, z) in enumerate(spots):
        center = c2w[:3, :3] @ np.array([x, y, z]) + c2w[:3, 3]
        pix, depth = project(center, c2w, k, w, h)
        px, py = pix[0]
        col, row = int(np.floor(px)), int(np.floor(py))
        assert (col > w / 2) == (x > 0) and (row > h / 2) == (y > 0) or x == 0
        assert out["surface"][row, col] == surface_base + i, (i, px, py)
        assert abs(depth[0] - z) < 1e-9
        assert abs(out["depth"][row, col] - z) < 0.031      # front of a 3 cm sphere
        v = center - c2w[:3, 3]
        cosang = float(rays[:, row, col] @ v / np.linalg.norm(v))
        pixel_angle = 1.0 / (k[0] * w)
        assert np.arccos(min(1.0, cosang)) < pixel_angle, i
    # poses: proper rotations, canonical view is the identity
    s = generate_scene(4, 3, (h, w))
    for m in s["c2w"]:
        assert np.allclose(m[:3, :3].T @ m[:3, :3], np.eye(3)) and np.linalg.det(m[:3, :3]) > 0
    assert np.allclose(s["c2w_canonical"][s["canonical_index"]], np.eye(4))


def test_copy_paste_mask_matches_pasted_pixels():
    seed, src = dynamic_seed()
    static = generate_scene(100, 4, 64, distractors=False)
    cp = copy_paste(static, src, seed=3)
    assert cp["kind"] == "copy-paste" and cp["mask"].any()
    for i, (dx, dy) in enumerate(cp["shifts"]):
        m = shift(src["mask"][i], dx, dy)
        assert np.array_equal(cp["mask"][i], m)
        assert np.array_equal(cp["rgb"][i][m], shift(src["rgb"][i], dx, dy)[m])
        assert np.array_equal(cp["rgb"][i][~m], static["rgb"][i][~m])
        assert np.array_equal(cp["classes"][i][~m], static["classes"][i][~m])
        assert np.isin(cp["classes"][i][m], DYN).all()
    assert np.array_equal(cp["c2w"], static["c2w"])
    again = copy_paste(static, src, seed=3)
    assert again["rgb"].tobytes() == cp["rgb"].tobytes()
    with pytest.raises(ValueError):
        copy_paste(static, generate_scene(1, 3, 64), seed=0)


def test_splits_are_disjoint():
    train, test = split_seeds("train", 50), split_seeds("test", 50)
    assert not set(train) & set(test)
    with pytest.raises(ValueError):
        split_seeds("val", 1)


# ----------------------------------------------------------------------------- CLI
def test_cli_writes_the_documented_files(tmp_path):
    from PIL import Image
    from spar_reference.cameras import read_transforms
    out = tmp_path / "scene"
    p = run("generate", "--seed", 6, "--frames", 3, "--size", "64x48", "--depth", "--out", out)
    assert p.returncode == 0, p.stderr
    names = sorted(os.listdir(out))
    want = sorted([f"{k}_{i:02d}.png" for k in ("rgb", "class", "mask") for i in range(3)]
                  + ["scene.json", "classes.json", "transforms.json", "depth.npy"])
    assert names == want
    meta = json.load(open(out / "scene.json"))
    api = generate_scene(6, 3, (48, 64))
    assert meta["seed"] == 6 and meta["kind"] == "dynamic" and meta["n_frames"] == 3
    assert (meta["width"], meta["height"]) == (64, 48)
    assert [c["name"] for c in meta["classes"]] == list(CLASS_NAMES)
    assert meta["frames_with_distractors"] == [int(i) for i in api["has_distractors"].nonzero()[0]]
    for i, fr in enumerate(meta["frames"]):
        assert np.array_equal(np.array(Image.open(out / fr["rgb"])), api["rgb"][i])
        assert np.array_equal(np.array(Image.open(out / fr["classes"])), api["classes"][i])
        assert np.array_equal(np.array(Image.open(out / fr["mask"])) == 255, api["mask"][i])
        assert np.allclose(fr["c2w_opencv"], api["c2w"][i])
    assert np.array_equal(np.load(out / "depth.npy"), api["depth"])
    c2w, k = read_transforms(str(out / "transforms.json"), 64, 48)
    assert np.allclose(c2w, api["c2w_canonical"]) and np.allclose(k, api["fxfycxcy"])
    # the same command twice: the same bytes
    out2 = tmp_path / "again"
    assert run("generate", "--seed", 6, "--frames", 3, "--size", "64x48", "--depth",
               "--out", out2).returncode == 0
    for n in names:
        assert (out / n).read_bytes() == (out2 / n).read_bytes(), n


def test_cli_split_static_and_copy_paste(tmp_path):
    p = run("split", "--split", "test", "--count", 2, "--kind", "copy-paste", "--frames", 2,
            "--size", 32, "--out", tmp_path / "cp")
    assert p.returncode == 0, p.stderr
    index = json.load(open(tmp_path / "cp" / "index.json"))
    assert [e["seed"] for e in index["scenes"]] == split_seeds("test", 2)
    assert all(e["kind"] == "copy-paste" and e["source_seed"] == e["seed"] + 1 for e in index["scenes"])
    p = run("generate", "--seed", 2, "--static", "--frames", 2, "--size", 32, "--out", tmp_path / "st")
    assert p.returncode == 0, p.stderr
    meta = json.load(open(tmp_path / "st" / "scene.json"))
    assert meta["kind"] == "static" and meta["frames_with_distractors"] == []


@pytest.mark.parametrize("args,code", [
    (["generate", "--seed", "-1"], 2),
    (["generate", "--seed", "x"], 2),
    (["generate", "--seed", "1", "--size", "0"], 2),
    (["generate", "--seed", "1", "--size", "12y4"], 2),
    (["generate", "--seed", "1", "--frames", "0"], 2),
    (["split", "--split", "val", "--count", "1"], 2),
    (["split", "--split", "test", "--count", "999999999"], 1),
    (["generate", "--seed", "1", "--static", "--paste-from", "2"], 1),
    (["bogus"], 2),
])
def test_cli_bad_arguments_one_line(tmp_path, args, code):
    got, err = run_in_process(*args, "--out", tmp_path / "o")
    assert got == code, err
    assert err.startswith("spar-scenes: error: ") and err.count("\n") == 1, err
    assert not os.listdir(tmp_path)


def test_cli_refuses_existing_output(tmp_path):
    (tmp_path / "o").mkdir()
    p = run("generate", "--seed", 1, "--out", tmp_path / "o")
    assert p.returncode == 1 and "exists" in p.stderr and p.stderr.count("\n") == 1
