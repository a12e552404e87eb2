#!/usr/bin/python3
"""``spar-train``'s run options for a GPU run (issue 14): held-out measurement during training
(--eval-scenes), a time budget (--minutes), --device, --image-size. A few scenes and steps on
the CPU keep each run to seconds.
Run: cd /work/main && /usr/bin/python3 -m pytest -q converter/tests/test_train_run.py
"""

import json
import os
import subprocess
import sys

import pytest
import torch

HERE = os.path.dirname(os.path.abspath(__file__))
TOOL = os.path.join(HERE, "..", "spar-train")
SCENES_TOOL = os.path.join(HERE, "..", "spar-scenes")


def train(out, *args, cache=None):
    cmd = [sys.executable, TOOL, "--out", str(out), "--scenes", "4", "--lseg-steps", "2",
           "--threads", "1", "--save-every", "0", "--log-every", "1", "--no-pack"]
    if cache:
        cmd += ["--cache", str(cache)]
    return subprocess.run(cmd + list(args), capture_output=True, text=True, timeout=900)


@pytest.fixture(scope="module")
def val_scenes(tmp_path_factory):
    d = tmp_path_factory.mktemp("val") / "scenes"
    subprocess.run([sys.executable, SCENES_TOOL, "split", "--split", "test", "--count", "1",
                    "--start", "12", "--out", str(d)], check=True, capture_output=True)
    return d


def weights(run):
    return torch.load(os.path.join(run, "checkpoint.pt"))["model"]


def test_measuring_held_out_scenes_changes_no_weight(tmp_path, val_scenes):
    """The held-out measurement runs the model in eval mode between steps: it must leave the
    training exactly as it was (same seed: the same weights bit for bit)."""
    cache = tmp_path / "cache"
    plain = train(tmp_path / "plain", "--steps", "3", cache=cache)
    assert plain.returncode == 0, plain.stderr
    measured = train(tmp_path / "measured", "--steps", "3", "--eval-scenes", str(val_scenes),
                     "--eval-every", "2", cache=cache)
    assert measured.returncode == 0, measured.stderr
    a, b = weights(tmp_path / "plain"), weights(tmp_path / "measured")
    assert list(a) == list(b)
    for k in a:
        assert torch.equal(a[k], b[k]), k
    curve = [json.loads(line) for line in open(tmp_path / "measured" / "curve.jsonl")]
    # before training, every --eval-every steps and the last step
    assert [c["step"] for c in curve] == [0, 2, 3]
    for c in curve:
        assert c["views"] == 3
        for key in ("psnr", "ssim", "psnr_nearest_input", "psnr_mean_colour", "sem_miou",
                    "mask_miou"):
            assert c[key] is not None and c[key] == c[key], key
        assert 5.0 < c["psnr"] < 60.0
    # the baselines do not depend on the model
    assert len({c["psnr_nearest_input"] for c in curve}) == 1
    assert "held-out step 3" in measured.stdout and "copy" in measured.stdout


def test_time_budget_fits_the_schedule(tmp_path, val_scenes):
    """--minutes: the step rate is measured after the first steps and the schedule's length
    set from it; the run stops near the budget, with its last step measured and saved."""
    p = train(tmp_path / "run", "--steps", "100000", "--minutes", "0.5", "--eval-scenes",
              str(val_scenes), "--eval-every", "10", cache=tmp_path / "cache")
    assert p.returncode == 0, p.stderr
    assert "time budget 0.5 min" in p.stdout
    total = int(p.stdout.split("time budget 0.5 min")[1].split("->")[1].split()[0])
    assert 5 < total < 100000
    ck = torch.load(tmp_path / "run" / "checkpoint.pt")
    steps = ck["param_update_step"]
    assert min(total, 8) <= steps <= total   # calibrated after at least 5 + 2 steps
    curve = [json.loads(line) for line in open(tmp_path / "run" / "curve.jsonl")]
    assert curve[-1]["step"] == steps
    assert curve[-1]["minutes"] < 0.5 * 1.1 + 0.2
    # a checkpoint written on any device holds CPU tensors (spar-convert reads those only)
    assert all(v.device.type == "cpu" for v in ck["model"].values())


def test_scene_tokens_size_the_latent(tmp_path):
    """--scene-tokens N: the scene latent (scene_code) has N rows, config.json says so, and the
    converter packs it against that config (the GPU variant with 192 tokens goes this way)."""
    p = train(tmp_path / "run", "--steps", "1", "--scene-tokens", "24", cache=tmp_path / "cache")
    assert p.returncode == 0, p.stderr
    assert tuple(weights(tmp_path / "run")["scene_code"].shape) == (24, 128)
    assert json.load(open(tmp_path / "run" / "config.json"))["scene_tokens"] == 24
    conv = subprocess.run([sys.executable, os.path.join(HERE, "..", "spar-convert"), "-q",
                           str(tmp_path / "run" / "checkpoint.pt"), "--config",
                           str(tmp_path / "run" / "config.json"), "-o", str(tmp_path / "m.spar")],
                          capture_output=True, text=True, timeout=300)
    assert conv.returncode == 0 and (tmp_path / "m.spar").stat().st_size > 0, conv.stderr


@pytest.mark.parametrize("args, message", [
    (["--device", "cuda:99"], "CUDA device"),   # no CUDA here; on a GPU machine: no 100th GPU
    (["--device", "tpu"], "--device tpu"),
    (["--image-size", "40"], "multiple of 16"),
    (["--minutes", "-1"], "--minutes"),
    (["--scene-tokens", "0"], "--scene-tokens"),
    (["--eval-scenes", "/nonexistent/scenes"], "not a directory"),
])
def test_bad_options_are_one_line_errors(tmp_path, args, message):
    p = train(tmp_path / "run", "--steps", "1", *args)
    assert p.returncode != 0
    lines = [line for line in p.stderr.strip().splitlines() if line]
    assert len(lines) == 1 and message in lines[0], p.stderr
    assert "Traceback" not in p.stderr
    assert not (tmp_path / "run" / "checkpoint.pt").exists()
