#!/usr/bin/python3
"""Tests of the reference's command-line tool ``reference/spar-reference`` (tiny config).

Commands run through spar_reference.cli.main in this process with one torch thread (an import
of torch and the model code per command would cost more than the command); the executable
itself runs in a subprocess twice, as a user would: a render (compared byte for byte with the
same render in this process: determinism across processes) and a refused command. The
checkpoint is made once per module (make-checkpoint --perturb --no-optimizer). Inputs are small
random PNGs of odd, non-square sizes (so resize and centre crop take part).

Run: cd /work/main && /usr/bin/python3 -m pytest -q reference/tests/test_reference_cli.py
"""

import io
import json
import os
import subprocess
import sys
import types
from contextlib import redirect_stderr, redirect_stdout

import numpy as np
import pytest
import torch

HERE = os.path.dirname(os.path.abspath(__file__))

from spar_reference import config as spar_config  # noqa: E402
from spar_reference.images import crop_geometry, load_image, to_uint8  # noqa: E402
from spar_reference.cameras import interpolate_path, mat_to_quat, quat_to_mat  # noqa: E402
from spar_reference.cli import main  # noqa: E402

TOOL = os.path.join(HERE, "..", "spar-reference")
REPO = os.path.dirname(os.path.dirname(HERE))
BPE_PATH = os.environ.get("SPAR_CLIP_BPE", os.path.join(REPO, "text", "data", "clip", "bpe_simple_vocab_16e6.txt.gz"))

CFG = spar_config.tiny()
H, W = CFG.image_height, CFG.image_width
FLIP = np.diag([1.0, -1.0, -1.0, 1.0])


torch.set_num_threads(1)


def run_executable(*args, check=True):
    """The spar-reference script in a subprocess (one torch thread)."""
    p = subprocess.run([sys.executable, TOOL] + [str(a) for a in args] + ["--threads", "1"],
                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, timeout=300)
    if check:
        assert p.returncode == 0, p.stderr
    return p


def run(*args, check=True):
    """The same command through spar_reference.cli.main in this process (one torch thread):
    exit code, stdout and stderr as the subprocess would give them."""
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            code = main([str(a) for a in args] + ["--threads", "1"])
        except SystemExit as e:     # argparse's usage errors
            code = e.code
    p = types.SimpleNamespace(returncode=code, stdout=out.getvalue(), stderr=err.getvalue())
    if check:
        assert p.returncode == 0, p.stderr
    return p


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    from PIL import Image
    d = tmp_path_factory.mktemp("cli")
    rng = np.random.default_rng(7)
    frames = []
    for i in range(5):
        a = (rng.random((97 + 6 * i, 151, 3)) * 255).astype(np.uint8)
        p = d / f"frame_{i}.png"
        Image.fromarray(a).save(p)
        frames.append(str(p))
    ckpt = d / "ckpt_spar_tiny.pt"
    run("make-checkpoint", "--config", "tiny", "-o", ckpt, "--seed", 3, "--perturb", "--no-optimizer")
    return {"dir": d, "frames": frames, "ckpt": str(ckpt)}


def png(path):
    from PIL import Image
    with Image.open(path) as im:
        return im.mode, im.size, np.asarray(im).copy()


def listing(d):
    return sorted(os.listdir(d))


def check_common(out, n_inputs, n_rendered):
    names = listing(out)
    views = [f"view_{j:02d}.png" for j in range(n_rendered)]
    motion = [f"motion_{j:02d}.png" for j in range(n_inputs)]
    masks = [f"mask_{j:02d}.png" for j in range(n_inputs)]
    assert [n for n in names if n.startswith("view_")] == views
    assert [n for n in names if n.startswith("motion_")] == motion
    assert [n for n in names if n.startswith("mask_")] == masks
    for v in views:
        mode, size, _ = png(out / v)
        assert (mode, size) == ("RGB", (W, H))
    for m in motion:
        mode, size, _ = png(out / m)
        assert (mode, size) == ("L", (W, H))
    for m in masks:
        mode, size, a = png(out / m)
        assert (mode, size) == ("L", (W, H))
        assert set(np.unique(a)) <= {0, 255}
    report = json.loads((out / "report.json").read_text())
    assert report["device"] == "pytorch-cpu" and report["precision"] == "fp32"
    assert report["total_seconds"] > 0
    stages = [s["name"] for s in report["stages"]]
    for s in ("load_checkpoint", "prepare_images", "image_tokens", "pose_encoder", "pose_head",
              "dino", "cv_drp", "lseg", "scene_encoder", "decoder", "rgb_head", "write_outputs"):
        assert s in stages, s
    assert all(s["seconds"] >= 0 for s in report["stages"])
    cams = json.loads((out / "cameras.json").read_text())
    return names, report, stages, cams


def check_cameras(cams, files, inputs):
    v = len(files)
    assert cams["canonical_index"] == v // 2
    assert [o["index"] for o in cams["order"]] == list(range(v))
    assert [os.path.basename(o["file"]) for o in cams["order"]] == [os.path.basename(f) for f in files]
    assert [o["role"] for o in cams["order"]] == ["input" if i in inputs else "target" for i in range(v)]
    assert cams["inputs"] == list(inputs)
    assert cams["targets"] == [i for i in range(v) if i not in inputs]
    assert len(cams["frames"]) == v
    for i, fr in enumerate(cams["frames"]):
        tm = np.array(fr["transform_matrix"])
        cv = np.array(fr["c2w_opencv"])
        assert np.allclose(tm @ FLIP, cv, atol=1e-12)
        assert np.allclose(cv[:3, :3] @ cv[:3, :3].T, np.eye(3), atol=1e-5)
        assert np.allclose(cv[3], [0, 0, 0, 1])
        k = fr["intrinsics_normalized"]
        assert fr["w"] == W and fr["h"] == H
        assert fr["fl_x"] == pytest.approx(k["fx"] * W) and fr["cy"] == pytest.approx(k["cy"] * H)
        assert fr["cx"] == pytest.approx(W / 2) and fr["cy"] == pytest.approx(H / 2)
        assert fr["fl_x"] == pytest.approx(cams["frames"][0]["fl_x"])  # one focal for all views
    # the canonical (middle) view is the identity in OpenCV axes
    can = cams["frames"][v // 2]
    assert np.allclose(np.array(can["c2w_opencv"]), np.eye(4), atol=1e-6)
    # perturbed pose heads: the other views are not the identity
    assert not np.allclose(np.array(cams["frames"][0]["c2w_opencv"]), np.eye(4), atol=1e-3)


# ----------------------------------------------------------------------------- make-checkpoint
def test_make_checkpoint_layout(work):
    ck = torch.load(work["ckpt"], map_location="cpu")
    assert set(ck) == {"model", "optimizer", "lr_scheduler", "fwdbwd_pass_step", "param_update_step"}
    sd = ck["model"]
    assert ck["optimizer"]["state"] == {}  # --no-optimizer: param groups only
    assert "scene_code" in sd and "_dino_v3.mean" in sd
    assert any(k.startswith("lseg_model.pretrained.") for k in sd)
    assert "lseg_model.clip_pretrained.token_embedding.weight" in sd
    assert "lseg_model.clip_pretrained.text_projection" in sd
    assert all(v.dtype in (torch.float32, torch.int64) for v in sd.values())
    assert not [n for n in listing(work["dir"]) if ".tmp-" in n]


# ----------------------------------------------------------------------------- render
def test_render_images_and_targets(work, tmp_path):
    f = work["frames"]
    out = tmp_path / "r"
    run("render", "--checkpoint", work["ckpt"], "--images", f[0], f[1], f[2],
        "--targets", f[3], f[4], "--out", out)
    names, report, stages, cams = check_common(out, 3, 2)
    for s in ("semantic_head", "text_encoder", "labels"):
        assert s not in stages
    assert not [n for n in names if n.startswith(("labels_", "features_"))]
    check_cameras(cams, f, [0, 1, 2])
    assert cams["render"] == "targets" and "render_frames" not in cams
    assert report["views"] == {"total": 5, "inputs": 3, "targets": 2, "rendered": 2}
    assert not [n for n in listing(tmp_path) if ".tmp-" in n]


def test_render_frames_inputs_is_deterministic_and_matches_goldens(work, tmp_path):
    """The executable's render and the same render in this process give the same bytes."""
    f = work["frames"]
    args = ["--checkpoint", work["ckpt"], "--frames"] + f + ["--inputs", "0,3,4"]
    run_executable("render", *args, "--out", tmp_path / "a")
    run("render", *args, "--out", tmp_path / "b")
    run("goldens", *args, "--out", tmp_path / "g")
    a, b = tmp_path / "a", tmp_path / "b"
    names, _, _, cams = check_common(a, 3, 2)
    check_cameras(cams, f, [0, 3, 4])
    assert listing(a) == listing(b)
    for n in names:
        if n != "report.json":
            assert (a / n).read_bytes() == (b / n).read_bytes(), n
    # the PNGs are the goldens' tensors
    g = tmp_path / "g"
    rgb = np.load(g / "rgb.npy")[0]
    prob = np.load(g / "cv_drp_input.prob.npy")[0, :, 0]
    binary = np.load(g / "cv_drp_input.binary.npy")[0, :, 0]
    for j in range(2):
        assert np.array_equal(png(a / f"view_{j:02d}.png")[2], to_uint8(rgb[j]).transpose(1, 2, 0))
    for j in range(3):
        assert np.array_equal(png(a / f"motion_{j:02d}.png")[2], to_uint8(prob[j]))
        assert np.array_equal(png(a / f"mask_{j:02d}.png")[2] == 255, binary[j] == 1)
    c2w = np.load(g / "c2w.npy")[0]
    for i in range(5):
        assert np.allclose(np.array(cams["frames"][i]["c2w_opencv"]), c2w[i], atol=1e-7)


def test_render_path(work, tmp_path):
    f = work["frames"]
    out = tmp_path / "p"
    run("render", "--checkpoint", work["ckpt"], "--images", f[0], f[1], f[2], "--path", 3,
        "--out", out)
    names, report, _, cams = check_common(out, 3, 3)
    check_cameras(cams, f[:3], [0, 1, 2])
    assert cams["render"] == "path" and len(cams["render_frames"]) == 3
    rf = [np.array(r["c2w_opencv"]) for r in cams["render_frames"]]
    fr = [np.array(cams["frames"][i]["c2w_opencv"]) for i in range(3)]
    # 3 frames along 3 inputs: exactly the input cameras
    for j in range(3):
        assert np.allclose(rf[j], fr[j], atol=1e-5)
    assert report["views"]["rendered"] == 3


def test_render_cameras_transforms_json(work, tmp_path):
    f = work["frames"]
    # two cameras in OpenGL c2w, intrinsics for an image of twice the model size
    th = 0.2
    rot = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    m0 = np.eye(4)
    m1 = np.eye(4)
    m1[:3, :3] = rot
    m1[:3, 3] = [0.1, -0.2, 0.3]
    doc = {"fl_x": 300.0, "fl_y": 310.0, "cx": 2 * W / 2, "cy": 2 * H / 2, "w": 2 * W, "h": 2 * H,
           "frames": [{"file_path": "a.png", "transform_matrix": m0.tolist()},
                      {"file_path": "b.png", "transform_matrix": m1.tolist(), "cx": W + 8.0}]}
    tj = tmp_path / "transforms.json"
    tj.write_text(json.dumps(doc))
    out = tmp_path / "c"
    run("render", "--checkpoint", work["ckpt"], "--images", f[0], f[1], "--targets", f[2],
        "--cameras", tj, "--out", out)
    names, report, _, cams = check_common(out, 2, 2)
    check_cameras(cams, f[:3], [0, 1])
    assert cams["render"] == "cameras"
    r0, r1 = cams["render_frames"]
    assert np.allclose(np.array(r0["c2w_opencv"]), m0 @ FLIP, atol=1e-6)
    assert np.allclose(np.array(r1["c2w_opencv"]), m1 @ FLIP, atol=1e-6)
    assert np.allclose(np.array(r1["transform_matrix"]), m1, atol=1e-6)
    # intrinsics carried through the 2x resize: pixels halve, normalized values stay
    assert r0["fl_x"] == pytest.approx(150.0, rel=1e-6) and r0["fl_y"] == pytest.approx(155.0, rel=1e-6)
    assert r0["intrinsics_normalized"]["fx"] == pytest.approx(300.0 / (2 * W), rel=1e-6)
    assert r1["cx"] == pytest.approx(W / 2 + 4.0, rel=1e-6)
    # feeding our own cameras.json back renders the estimated cameras: targets reproduce
    out2 = tmp_path / "c2"
    run("render", "--checkpoint", work["ckpt"], "--images", f[0], f[1], "--targets", f[2],
        "--out", out2)
    out3 = tmp_path / "c3"
    run("render", "--checkpoint", work["ckpt"], "--images", f[0], f[1], "--targets", f[2],
        "--cameras", out2 / "cameras.json", "--out", out3)
    a = png(out2 / "view_00.png")[2].astype(int)
    b = png(out3 / "view_02.png")[2].astype(int)
    assert np.abs(a - b).max() <= 1


def test_render_labels_and_features(work, tmp_path):
    f = work["frames"]
    out = tmp_path / "l"
    prompts = ["a cat", "grass", "the sky"]
    run("render", "--checkpoint", work["ckpt"], "--images", f[0], f[1], "--targets", f[2], f[3],
        "--labels", ",".join(prompts), "--features", "--bpe", BPE_PATH, "--out", out)
    names, report, stages, _ = check_common(out, 2, 2)
    for s in ("semantic_head", "text_encoder", "labels"):
        assert s in stages
    for j in range(2):
        mode, size, _ = png(out / f"labels_{j:02d}.png")
        assert mode == "RGB" and size[0] == W and size[1] >= H
        doc = json.loads((out / f"labels_{j:02d}.json").read_text())
        assert list(doc["legend"]) == prompts
        assert [e["label"] for e in doc["labels"]] == prompts
        assert sum(e["share"] for e in doc["labels"]) == pytest.approx(1.0, abs=1e-12)
        assert sum(e["pixels"] for e in doc["labels"]) == H * W  # the map is at the image size
        feat = np.load(out / f"features_{j:02d}.npy")
        assert feat.dtype == np.float32 and feat.shape == (CFG.semantic_dim, H // 2, W // 2)
    assert "labels_02.json" not in names


# ----------------------------------------------------------------------------- goldens
GOLDEN_STAGES = {"inputs", "image_tokens", "pose_encoder", "pose_head", "rays", "dino", "cv_drp",
                 "gating", "lseg", "semantic_tokens", "scene_encoder", "render_cameras", "decoder",
                 "rgb_head", "semantic_head", "text_encoder", "labels", "layers"} - {"layers"}
GOLDEN_NAMES = {"images", "c2w", "fxfycxcy", "cam_info", "plucker", "ray_tokens", "img_tokens",
                "dino", "cv_drp_input.prob", "cv_drp_input.binary", "cv_drp_target.prob",
                "gated_tokens", "lseg_features", "gated_semantic_tokens", "scene_tokens",
                "decoder_out", "rgb", "semantic_features", "text_embeddings", "label_logits",
                "label_maps", "layers.transformer_decoder.00"}


def test_goldens_manifest(work, tmp_path):
    f = work["frames"]
    out = tmp_path / "g"
    run("goldens", "--checkpoint", work["ckpt"], "--frames", *f, "--inputs", "0,2,4",
        "--labels", "tree,car", "--bpe", BPE_PATH, "--out", out)
    man = json.loads((out / "manifest.json").read_text())
    assert man["format"] == "spar-reference-goldens" and man["precision"] == "fp32"
    assert man["inputs"] == [0, 2, 4] and man["targets"] == [1, 3]
    assert man["labels"] == ["tree", "car"]
    files = man["files"]
    assert GOLDEN_STAGES <= {e["stage"] for e in files}
    assert GOLDEN_NAMES <= {e["name"] for e in files}
    on_disk = {n for n in listing(out) if n.endswith(".npy")}
    assert on_disk == {e["file"] for e in files}
    for e in files:
        a = np.load(out / e["file"])
        assert list(a.shape) == e["shape"] and str(a.dtype) == e["dtype"], e
        assert e["dtype"] in ("float32", "int32") and e["description"]
        if a.dtype == np.float32:
            assert np.isfinite(a).all(), e["file"]
    shapes = {e["name"]: e["shape"] for e in files}
    assert shapes["images"] == [5, 3, H, W]
    assert shapes["rgb"] == [1, 2, 3, H, W]
    # the label maps at the image's size, in the official order (logits x2, then the argmax)
    assert shapes["label_maps"] == [2, H, W] and shapes["label_logits"][2:] == [H // 2, W // 2]
    from spar_reference.clip_text import full_resolution_labels
    logits = torch.from_numpy(np.load(out / "label_logits.npy")).double()
    assert np.array_equal(np.load(out / "label_maps.npy"), full_resolution_labels(logits).numpy())
    assert shapes["cv_drp_input.prob"] == [1, 3, 1, H, W]
    # the prepared images are the preparation rule applied to the files
    imgs = np.load(out / "images.npy")
    assert np.array_equal(imgs[1], load_image(f[1], H, W))


def test_goldens_without_labels_float64(work, tmp_path):
    f = work["frames"]
    out = tmp_path / "g64"
    run("goldens", "--checkpoint", work["ckpt"], "--config", "tiny", "--images", f[0], f[1],
        "--path", 2, "--float64", "--out", out)
    man = json.loads((out / "manifest.json").read_text())
    assert man["precision"] == "fp64" and man["render"] == "path"
    names = {e["name"] for e in man["files"]}
    assert "label_maps" not in names and "text_embeddings" not in names
    assert "semantic_features" in names and "render_c2w" in names
    assert {e["dtype"] for e in man["files"]} == {"float64", "int32"}


# ----------------------------------------------------------------------------- errors
def error_args(work, tmp_path, case):
    f = work["frames"]
    bad = tmp_path / "bad.png"
    bad.write_text("not an image")
    return [str(x) for x in {
        "missing_image": ["--checkpoint", work["ckpt"], "--images", f[0], tmp_path / "nope.png"],
        "one_input": ["--checkpoint", work["ckpt"], "--images", f[0], "--targets", f[1]],
        "no_checkpoint": ["--checkpoint", tmp_path / "nope.pt", "--images", f[0], f[1]],
        "bad_image": ["--checkpoint", work["ckpt"], "--images", f[0], bad],
        "not_a_checkpoint": ["--checkpoint", f[0], "--images", f[0], f[1]],
        "bad_inputs": ["--checkpoint", work["ckpt"], "--frames", f[0], f[1], "--inputs", "0,7"],
        "wrong_config": ["--checkpoint", work["ckpt"], "--config", "full", "--images", f[0], f[1]],
        "labels_no_bpe": ["--checkpoint", work["ckpt"], "--images", f[0], f[1], "--labels", "a",
                          "--bpe", tmp_path / "nope.txt.gz"],
        # SAM2.1 refinement: no SAM2 file; a missing one; not with a static scene; a SPAR
        # checkpoint in its place (no variant matches its tensors)
        "refine_no_sam2": ["--checkpoint", work["ckpt"], "--images", f[0], f[1], "--refine"],
        "refine_missing_sam2": ["--checkpoint", work["ckpt"], "--images", f[0], f[1], "--mask-source", "refined",
                                "--sam2", tmp_path / "nope.pt"],
        "refine_static": ["--checkpoint", work["ckpt"], "--images", f[0], f[1], "--refine", "--assume-static",
                          "--sam2", work["ckpt"]],
        "refine_not_sam2": ["--checkpoint", work["ckpt"], "--images", f[0], f[1], "--refine", "--sam2", work["ckpt"]],
    }[case]]


def check_error(code, stderr, out, tmp_path):
    assert code == 1, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("spar-reference: error: "), stderr
    assert "Traceback" not in stderr
    assert not out.exists()
    assert not [n for n in listing(tmp_path) if ".tmp-" in n]


# The executable's error path once (its exit code, one line, no traceback, nothing written); the
# cases one_input and no_checkpoint, and goldens, are refused the same way in
# test_errors_in_process (render and goldens each).
def test_errors_executable(work, tmp_path):
    out = tmp_path / "out"
    p = run_executable("render", *error_args(work, tmp_path, "missing_image"), "--out", out,
                       check=False)
    check_error(p.returncode, p.stderr, out, tmp_path)


@pytest.mark.parametrize("case", ["missing_image", "one_input", "no_checkpoint", "bad_image",
                                  "not_a_checkpoint", "bad_inputs", "labels_no_bpe", "refine_no_sam2",
                                  "refine_missing_sam2", "refine_static", "refine_not_sam2"])
def test_errors_in_process(work, tmp_path, case, capsys):
    out = tmp_path / "out"
    for cmd in ("render", "goldens"):
        code = main([cmd] + error_args(work, tmp_path, case) + ["--out", str(out), "--threads", "1"])
        check_error(code, capsys.readouterr().err, out, tmp_path)


def test_error_wrong_config(work, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["render"] + error_args(work, tmp_path, "wrong_config")
                + ["--out", str(out), "--threads", "1"])
    err = capsys.readouterr().err
    check_error(code, err, out, tmp_path)
    assert "does not match" in err


def test_help_of_each_subcommand(capsys):
    # (the program name is spar_reference.cli.PROG, not argv[0]: the same in a subprocess)
    for cmd in ("make-checkpoint", "render", "goldens", "batch"):
        with pytest.raises(SystemExit) as e:
            main([cmd, "--help"])
        assert e.value.code == 0
        assert "usage: spar-reference " + cmd in capsys.readouterr().out


def test_batch_runs_every_command_line_in_one_process(work, tmp_path, capsys):
    """batch: each run as it runs alone, a failing one (here a usage error) does not stop the
    next, and the batch's exit code and last line say which failed."""
    f = work["frames"]
    a, b, bad = tmp_path / "a", tmp_path / "b", tmp_path / "bad"
    views = ["--checkpoint", work["ckpt"], "--images", f[0], f[1], "--targets", f[2], "--threads", "1"]
    runs = [["render"] + views + ["--out", str(a)],
            ["render"] + views + ["--bogus", "--out", str(bad)],
            ["goldens"] + views + ["--out", str(b)]]
    batch = tmp_path / "runs.json"
    batch.write_text(json.dumps(runs))
    assert main(["batch", str(batch)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == "spar-reference: error: 1 of 3 runs failed: run 1 (render, exit 2)", err
    assert (a / "view_00.png").is_file() and (b / "manifest.json").is_file() and not bad.exists()
    check_common(a, 2, 1)
    for text, why in (("[1, 2", "cannot read"), ("{}", "must hold a JSON list"), ('[["batch", "x"]]', "is a batch")):
        batch.write_text(text)
        assert main(["batch", str(batch)]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and why in err[0], err


def test_batch_ends_at_an_interrupt(work, tmp_path, capsys, monkeypatch):
    """Ctrl-C during a run ends the whole batch (one line), not only that run."""
    from spar_reference import cli

    def interrupted(args, state_dict=None):
        raise KeyboardInterrupt
    monkeypatch.setattr(cli, "cmd_render", interrupted)
    f = work["frames"]
    runs = [["render", "--checkpoint", work["ckpt"], "--images", f[0], f[1], "--out", str(tmp_path / f"r{i}")]
            for i in range(2)]
    batch = tmp_path / "runs.json"
    batch.write_text(json.dumps(runs))
    assert main(["batch", str(batch)]) == 1
    assert capsys.readouterr().err.strip().splitlines() == ["spar-reference: error: interrupted"]
    assert not (tmp_path / "r1").exists()


def test_config_inference(work, tmp_path):
    """Preset checkpoints give the preset (image size included); others the converter's
    inference from the tensors."""
    from spar_reference import cli
    sd = cli.load_checkpoint(work["ckpt"])
    assert cli.infer_config(sd, work["ckpt"]).to_dict() == CFG.to_dict()
    c = spar_config.tiny()
    c.scene_tokens, c.encoder_n_layer = 8, 1
    cj = tmp_path / "custom.json"
    c.save(str(cj))
    ck = tmp_path / "custom.pt"
    assert cli.main(["make-checkpoint", "--config", str(cj), "-o", str(ck), "--no-optimizer",
                     "--threads", "1"]) == 0
    inferred = cli.infer_config(cli.load_checkpoint(str(ck)), str(ck))
    assert (inferred.scene_tokens, inferred.encoder_n_layer, inferred.d) == (8, 1, c.d)


# ----------------------------------------------------------------------------- units
def test_image_preparation_rule(tmp_path):
    from PIL import Image
    assert crop_geometry(151, 97, 128, 128) == (199, 128, 35, 0)
    assert crop_geometry(128, 128, 128, 128) == (128, 128, 0, 0)
    assert crop_geometry(60, 200, 128, 128) == (128, 427, 0, 149)
    rng = np.random.default_rng(1)
    a = (rng.random((97, 151, 4)) * 255).astype(np.uint8)
    p = tmp_path / "rgba.png"
    Image.fromarray(a, "RGBA").save(p)
    x = load_image(str(p), 128, 128)
    ref = Image.fromarray(a, "RGBA").convert("RGB").resize((199, 128), Image.LANCZOS)
    ref = np.asarray(ref.crop((35, 0, 163, 128))).astype(np.float64) / 255.0
    assert x.dtype == np.float32 and x.shape == (3, 128, 128)
    assert np.array_equal(x, ref.transpose(2, 0, 1).astype(np.float32))


def test_path_interpolation():
    rng = np.random.default_rng(2)
    cams = []
    for _ in range(3):
        q = rng.normal(size=4)
        m = np.eye(4)
        m[:3, :3] = quat_to_mat(q / np.linalg.norm(q))
        m[:3, 3] = rng.normal(size=3)
        cams.append(m)
    cams = np.stack(cams)
    for c in cams:
        assert np.allclose(quat_to_mat(mat_to_quat(c[:3, :3])), c[:3, :3], atol=1e-12)
    p = interpolate_path(cams, 5)
    assert p.shape == (5, 4, 4)
    assert np.allclose(p[0], cams[0]) and np.allclose(p[2], cams[1]) and np.allclose(p[4], cams[2])
    assert np.allclose(p[1, :3, 3], (cams[0, :3, 3] + cams[1, :3, 3]) / 2)
    for m in p:
        assert np.allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-12)
    assert interpolate_path(cams, 1).shape == (1, 4, 4)
