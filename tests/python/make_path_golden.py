#!/usr/bin/python3
"""Goldens for tests/test_cameras.cpp: the reference's camera functions
(reference/spar_reference/cameras.py) in float64, written as JSON (Python's repr of a float
round-trips, so the C++ side reads exactly the values used here).

Writes into --out:
  golden.json {
    "quat":       [{"name", "r" 3x3, "q" (w,x,y,z)}]            mat_to_quat, every Shepperd branch
    "slerp":      [{"name", "q0", "q1", "u", "q"}]               slerp, incl. both sides of 0.9995
    "path":       [{"name", "c2w" [K,4,4], "n", "out" [N,4,4]}]  interpolate_path
    "entry":      [{"c2w" 4x4, "k", "w", "h", "extra", "out"}]   camera_entry
    "transforms": [{"name", "file", "out_w", "out_h",
                    "c2w" [R,4,4], "k" [R,4]  |  "error", "exact", "prefix"}] read_transforms
  }
  transforms_<name>.json  the files read_transforms read (a missing one is never written)

"exact": the reference raised its own CameraError, whose text the engine reproduces; otherwise
the JSON parser's words differ (then the message must start with "prefix") or the reference
failed elsewhere (numpy; prefix "") and only the failure itself must match.

Usage: make_path_golden.py --out DIR [--seed S]
"""

import argparse
import json
import math
import os
import sys

import numpy as np

from spar_reference.cameras import (CameraError, camera_entry, interpolate_path,  # noqa: E402
                                    mat_to_quat, quat_to_mat, read_transforms, slerp)


def axis_angle(axis, angle):
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    return quat_to_mat(np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * a]))


def random_rot(rng):
    return quat_to_mat(rng.standard_normal(4))


def c2w_of(r, t):
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = t
    return m


def path_cases(rng):
    eye = np.eye(3)
    cases = {}
    cams = [c2w_of(random_rot(rng), rng.standard_normal(3) * 2) for _ in range(4)]
    cases["random_k4_n9"] = (cams, 9)
    cases["random_k4_n50"] = (cams, 50)
    cases["random_k3_n1"] = (cams[:3], 1)          # N = 1: the first camera
    cases["random_k2_n2"] = (cams[:2], 2)          # N = 2: both ends exactly
    cases["random_k4_n3"] = (cams, 3)              # N < K: skips cameras
    cases["single_k1_n4"] = ([cams[0]], 4)         # K = 1: repeated
    cases["identical_k3_n5"] = ([cams[1]] * 3, 5)  # dot = 1: the lerp branch, no division by sin 0
    c = c2w_of(eye, [0, 0, 0])
    for ang, name in [(math.pi, "rot180_x"), (math.pi - 1e-3, "rot179.94_y"),
                      (math.pi - 1e-7, "rot180-1e-7_z"), (math.pi + 1e-3, "rot180+1e-3_xyz")]:
        axis = {"rot180_x": [1, 0, 0], "rot179.94_y": [0, 1, 0], "rot180-1e-7_z": [0, 0, 1],
                "rot180+1e-3_xyz": [1, 2, 3]}[name]
        cases[name] = ([c, c2w_of(axis_angle(axis, ang), [1, -2, 3])], 7)
    # dot products either side of the lerp threshold 0.9995 (half-angle acos(0.9995) = 0.0316)
    for ang, name in [(2 * math.acos(0.9994), "dot0.9994"), (2 * math.acos(0.9996), "dot0.9996")]:
        r0 = random_rot(rng)
        cases[name] = ([c2w_of(r0, [0, 0, 0]), c2w_of(r0 @ axis_angle([0.3, -1, 0.2], ang), [0, 0, 1])], 6)
    # the other hemisphere: q1 ~ -q0 after Shepperd's sign choice
    r0 = axis_angle([0, 0, 1], 0.1)
    cases["hemisphere"] = ([c2w_of(r0, [0, 0, 0]), c2w_of(axis_angle([0, 0, 1], -0.1 + 2 * math.pi - 1e-9), [0, 0, 0]),
                            c2w_of(random_rot(rng), [5, 5, 5])], 8)
    cases["far_translation"] = ([c2w_of(random_rot(rng), [1e3, -1e3, 2e3]), c2w_of(random_rot(rng), [0, 0, 0])], 4)
    out = []
    for name, (cs, n) in cases.items():
        cs = np.stack(cs)
        out.append({"name": name, "c2w": cs.tolist(), "n": n, "out": interpolate_path(cs, n).tolist()})
    return out


def quat_cases(rng):
    out = []
    mats = {
        "identity": np.eye(3),
        "random": random_rot(rng),
        "x180": axis_angle([1, 0, 0], math.pi),       # trace -1: the r00 branch
        "y180": axis_angle([0, 1, 0], math.pi),       # the r11 branch
        "z180": axis_angle([0, 0, 1], math.pi),       # the r22 branch
        "xyz179": axis_angle([1, 1, 1], math.pi - 1e-3),
        "tiny": axis_angle([0.2, 0.5, -1], 1e-9),
    }
    for name, r in mats.items():
        out.append({"name": name, "r": r.tolist(), "q": mat_to_quat(r).tolist()})
    return out


def slerp_cases(rng):
    out = []
    q0 = rng.standard_normal(4)
    q0 /= np.linalg.norm(q0)
    q1 = rng.standard_normal(4)
    q1 /= np.linalg.norm(q1)
    cases = [("random", q0, q1), ("same", q0, q0.copy()), ("opposite_sign", q0, -q0),
             ("orthogonal", np.array([1.0, 0, 0, 0]), np.array([0.0, 1, 0, 0]))]
    for name, a, b in cases:
        for u in (0.0, 0.25, 0.5, 1.0):
            out.append({"name": f"{name}_u{u}", "q0": a.tolist(), "q1": b.tolist(), "u": u,
                        "q": slerp(a, b, u).tolist()})
    return out


def entry_cases(rng):
    out = []
    for w, h in [(128, 128), (96, 64)]:
        c2w = c2w_of(random_rot(rng), rng.standard_normal(3))
        k = [1.3, 1.3, 0.5, 0.5] if w == h else [0.9, 1.25, 0.47, 0.52]
        extra = {"file_path": "/x/frame_0.png", "index": 0, "role": "input"} if w == h else {"index": 3, "role": "render"}
        out.append({"c2w": c2w.tolist(), "k": k, "w": w, "h": h, "extra": extra,
                    "out": camera_entry(c2w, k, w, h, **extra)})
    return out


def transforms_cases(out_dir, rng):
    def mat():
        return c2w_of(random_rot(rng), rng.standard_normal(3)).tolist()
    good = {
        "basic": {"fl_x": 160.0, "fl_y": 150.0, "cx": 64.0, "cy": 60.0, "w": 128, "h": 128,
                  "frames": [{"transform_matrix": mat()}, {"transform_matrix": mat()}]},
        "per_frame": {"fl_x": 100.0, "w": 128, "h": 128,
                      "frames": [{"transform_matrix": mat()},
                                 {"transform_matrix": mat(), "fl_x": 90.0, "cx": 70.5, "w": 256, "h": 256}]},
        "crop_160x120": {"fl_x": 110.0, "fl_y": 111.0, "cx": 81.0, "cy": 59.5, "w": 160, "h": 120,
                         "frames": [{"transform_matrix": mat()}]},
        "crop_odd_1001x333": {"fl_x": 700.0, "w": 1001, "h": 333, "frames": [{"transform_matrix": mat()}]},
        "defaults": {"fl_x": 128.0, "frames": [{"transform_matrix": mat()}]},
        "mat3x4": {"fl_x": 128.0, "frames": [{"transform_matrix": mat()[:3]}]},
        "string_numbers": {"fl_x": "120.5", "w": "128", "frames": [{"transform_matrix": mat()}]},
        "fractional_size": {"fl_x": 50.0, "w": 127.5, "h": 64.4, "frames": [{"transform_matrix": mat()}]},
    }
    bad = {
        "missing": None,
        "not_json": "{ this is not json",
        "top_list": [1, 2, 3],
        "no_frames": {"fl_x": 1.0},
        "empty_frames": {"fl_x": 1.0, "frames": []},
        "frame_not_object": {"fl_x": 1.0, "frames": [3]},
        "no_matrix": {"fl_x": 1.0, "frames": [{"file_path": "a.png"}]},
        "matrix_3x3": {"fl_x": 1.0, "frames": [{"transform_matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}]},
        "matrix_text": {"fl_x": 1.0, "frames": [{"transform_matrix": [["a", 0, 0, 0]] * 4}]},
        "matrix_ragged": {"fl_x": 1.0, "frames": [{"transform_matrix": [[1, 0, 0, 0], [0, 1, 0]]}]},
        "no_fl_x": {"frames": [{"transform_matrix": mat()}]},
        "negative_fl_x": {"fl_x": -3.0, "frames": [{"transform_matrix": mat()}]},
        "zero_w": {"fl_x": 3.0, "w": 0, "frames": [{"transform_matrix": mat()}]},
        "fl_x_text": {"fl_x": "abc", "frames": [{"transform_matrix": mat()}]},
        "second_frame_bad": {"fl_x": 3.0, "frames": [{"transform_matrix": mat()}, {"transform_matrix": mat(), "fl_y": -1}]},
    }
    results = []
    sizes = [(128, 128), (96, 64)]
    for name, doc in list(good.items()) + list(bad.items()):
        path = os.path.join(out_dir, f"transforms_{name}.json")
        if doc is not None:
            with open(path, "w") as f:
                f.write(doc if isinstance(doc, str) else json.dumps(doc))
        for ow, oh in sizes:
            r = {"name": name, "file": path, "out_w": ow, "out_h": oh}
            try:
                c2w, k = read_transforms(path, ow, oh)
                r["c2w"], r["k"] = c2w.tolist(), k.tolist()
            except CameraError as e:
                # the JSON parser's own words differ between Python and C++: only the prefix
                r["error"] = str(e)
                r["exact"] = not r["error"].startswith("cannot read cameras file")
                r["prefix"] = r["error"] if r["exact"] else f"cannot read cameras file {path}: "
            except Exception as e:  # noqa: BLE001 - the reference's own crash is still a failure
                r["error"], r["exact"], r["prefix"] = f"{e.__class__.__name__}: {e}", False, ""
            if (name in bad) != ("error" in r):
                raise SystemExit(f"case {name}: expected {'an error' if name in bad else 'success'}, got {r}")
            results.append(r)
    return results


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=11)
    a = ap.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    rng = np.random.default_rng(a.seed)
    doc = {"quat": quat_cases(rng), "slerp": slerp_cases(rng), "path": path_cases(rng),
           "entry": entry_cases(rng), "transforms": transforms_cases(os.path.abspath(a.out), rng)}
    with open(os.path.join(a.out, "golden.json"), "w") as f:
        json.dump(doc, f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
