#!/usr/bin/python3
"""Tests of the evaluation protocol's PyTorch side (evaluation/spar_eval, PROTOCOL.md).

Metrics against hand-computed values and a brute-force SSIM; the view index formula; an
end-to-end run of run_reference on two generated test scenes with the tiny semantic model in
the three modes; the command-line tools' exit codes (spar-eval-reference's refusals through its
main() in this process, one successful run of each tool as a subprocess).

Run: cd /work/main && /usr/bin/python3 -m pytest -q evaluation/tests/test_eval_metrics.py
"""

import io
import json
import math
import os
import subprocess
import sys
from contextlib import redirect_stderr, redirect_stdout

import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))
# The tools by name: spar-eval-* beside this folder, spar-scenes in the scene generator's.
TOOLS = {"spar-scenes": os.path.join(REPO, "scenes", "spar-scenes")}

from spar_eval import metrics  # noqa: E402
from spar_eval.protocol import ProtocolError, Scene, view_indices  # noqa: E402
from spar_eval.run_reference import METRIC_KEYS, Accumulator, Prediction  # noqa: E402

BPE_PATH = os.environ.get("SPAR_CLIP_BPE", os.path.join(REPO, "text", "data", "clip", "bpe_simple_vocab_16e6.txt.gz"))


def tool(name, *args):
    return subprocess.run([sys.executable, TOOLS.get(name, os.path.join(HERE, "..", name))] + [str(a) for a in args],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, timeout=600)


# ============================================================================ PSNR
def test_psnr_known_values():
    rng = np.random.default_rng(0)
    gt = rng.random((8, 9, 3))
    static = np.ones((8, 9), bool)
    assert metrics.psnr_static(gt + 0.1, gt, static) == pytest.approx(20.0, abs=1e-9)
    one = gt.copy()
    one[..., 1] += 0.1                       # error in one channel: mse = 0.01 / 3
    assert metrics.psnr_static(one, gt, static) == pytest.approx(10 * math.log10(300.0), abs=1e-9)
    # dynamic pixels do not count, whatever their error
    bad = gt + 0.1
    static[2:5, 3:7] = False
    bad[~static] = 5.0
    assert metrics.psnr_static(bad, gt, static) == pytest.approx(20.0, abs=1e-9)


def test_psnr_skips_view_without_static_pixels():
    gt = np.zeros((4, 4, 3))
    assert metrics.psnr_static(gt + 0.5, gt, np.zeros((4, 4), bool)) is None


# ============================================================================ SSIM
def brute_ssim(x, y, static):
    """Double loop over the valid centres with an independently built 2-D window."""
    r = np.arange(11) - 5.0
    w = np.exp(-(r[:, None] ** 2 + r[None, :] ** 2) / (2 * 1.5 ** 2))
    w /= w.sum()
    h, wd = static.shape
    vals = []
    for c in range(3):
        for cy in range(5, h - 5):
            for cx in range(5, wd - 5):
                if not static[cy, cx]:
                    continue
                a = x[cy - 5:cy + 6, cx - 5:cx + 6, c]
                b = y[cy - 5:cy + 6, cx - 5:cx + 6, c]
                ma, mb = (w * a).sum(), (w * b).sum()
                va = (w * a * a).sum() - ma * ma
                vb = (w * b * b).sum() - mb * mb
                cov = (w * a * b).sum() - ma * mb
                vals.append((2 * ma * mb + 1e-4) * (2 * cov + 9e-4)
                            / ((ma * ma + mb * mb + 1e-4) * (va + vb + 9e-4)))
    return float(np.mean(vals))


def test_ssim_identical_is_one():
    rng = np.random.default_rng(1)
    x = rng.random((20, 23, 3))
    assert metrics.ssim_static(x, x, np.ones((20, 23), bool)) == pytest.approx(1.0, abs=1e-12)


def test_ssim_matches_brute_force():
    rng = np.random.default_rng(2)
    x = rng.random((17, 19, 3))
    y = np.clip(x + 0.2 * rng.standard_normal(x.shape), 0, 1)
    static = rng.random((17, 19)) > 0.3
    got = metrics.ssim_static(x, y, static)
    assert got == pytest.approx(brute_ssim(x, y, static), abs=1e-12)
    assert 0.0 < got < 1.0


def test_ssim_window_and_skip():
    g = metrics.gaussian_window()
    assert g.shape == (11,) and np.outer(g, g).sum() == pytest.approx(1.0, abs=1e-15)
    x = np.zeros((16, 16, 3))
    static = np.zeros((16, 16), bool)
    static[:5, :] = True                     # static only where no window fits: no centre
    static[:, -5:] = True
    assert metrics.ssim_static(x, x + 0.1, static) is None
    static[5, 5] = True                      # the first valid centre
    assert metrics.ssim_static(x, x, static) == pytest.approx(1.0)


# ============================================================================ motion masks
def test_mask_counts_and_scores():
    gt = np.array([[1, 1, 0, 0], [0, 0, 0, 0]], bool)
    pred = np.array([[1, 0, 1, 0], [0, 0, 0, 0]], bool)
    c = metrics.mask_counts(pred, gt)
    assert c.tolist() == [1, 1, 1, 5]                      # TP FP FN TN
    s = metrics.mask_scores(c + metrics.mask_counts(gt, gt))   # accumulate a perfect frame
    tp, fp, fn, tn = 3, 1, 1, 11
    assert s["mask_iou_dynamic"] == pytest.approx(tp / (tp + fp + fn))
    assert s["mask_miou"] == pytest.approx((tp / (tp + fp + fn) + tn / (tn + fp + fn)) / 2)
    assert s["mask_recall"] == pytest.approx(tp / (tp + fn))
    # no dynamic pixel anywhere and none predicted: IoU_dyn / recall undefined -> null
    z = metrics.mask_scores(np.array([0, 0, 0, 10]))
    assert z["mask_iou_dynamic"] is None and z["mask_recall"] is None and z["mask_miou"] is None


# ============================================================================ semantics
def test_semantic_pixels_are_the_static_ones():
    """PROTOCOL.md, Semantics: the label maps are at the image's size; every static pixel counts."""
    classes = np.array([[0, 0, 1, 2],
                        [2, 2, 4, 1]])
    static = np.ones_like(classes, bool)
    static[1, 1] = False                     # a dynamic pixel: not evaluated
    ev, gt = metrics.semantic_targets(classes, static)
    assert ev.tolist() == [[True, True, True, True], [True, False, True, True]]
    assert gt.tolist() == classes.tolist()
    pred = np.array([[0, 1, 1, 2], [2, 9, 1, 1]])  # 9 at the excluded pixel: never looked at
    conf = metrics.confusion(pred, gt, ev, 5)
    assert conf.sum() == 7 and np.trace(conf) == 5
    s = metrics.semantic_scores(conf)
    assert s["sem_accuracy"] == pytest.approx(5 / 7)
    # classes with ground truth: 0, 1, 2, 4. IoU: 0 -> 1/2 (a 0 predicted 1), 1 -> 2/4 (TP 2, FP
    # from 0 and from 4), 2 -> 2/2, 4 -> 0/1; class 3 has no ground truth: left out
    assert s["sem_miou"] == pytest.approx((0.5 + 0.5 + 1 + 0) / 4)
    assert metrics.semantic_scores(np.zeros((3, 3), np.int64))["sem_miou"] is None


# ============================================================================ protocol
def test_view_indices():
    assert view_indices(8, 2) == ([0, 7], [1, 2, 3, 4, 5, 6])
    assert view_indices(8, 3) == ([0, 4, 7], [1, 2, 3, 5, 6])
    assert view_indices(8, 4) == ([0, 2, 5, 7], [1, 3, 4, 6])
    assert view_indices(5, 3)[0] == [0, 2, 4]
    assert view_indices(4, 3)[0] == [0, 2, 3]        # 1.5 + 0.5 = 2: a tie rounds up
    for bad in (1, 8, 9):
        with pytest.raises(ProtocolError):
            view_indices(8, bad)


def test_accumulator_skips_views():
    """A target frame that is all dynamic counts for neither PSNR nor SSIM nor semantics, but
    its motion mask still counts."""
    f, h, w = 3, 16, 16
    rgb = np.full((f, h, w, 3), 100, np.uint8)
    dyn = np.zeros((f, h, w), bool)
    dyn[1] = True
    scene = Scene("s", rgb, np.zeros((f, h, w), np.int64), dyn, ["wall", "floor"])
    targets = [1, 2]
    out = np.full((2, h, w, 3), 110 / 255.0)
    pred = Prediction(out, np.zeros((f, h, w), bool), np.zeros((2, h, w), np.int64), 0.1)
    acc = Accumulator(2)
    acc.add(scene, [0], targets, pred)
    r = acc.result(1.0)
    assert r["target_views"] == 2 and len(acc.psnr) == 1 and len(acc.ssim) == 1
    assert r["psnr"] == pytest.approx(10 * math.log10(1 / (10 / 255.0) ** 2))
    assert r["sem_accuracy"] == 1.0 and r["sem_miou"] == 1.0
    assert r["mask_recall"] == 0.0 and r["mask_iou_dynamic"] == 0.0
    assert r["ms_per_scene"] == pytest.approx(100.0)


def test_nearest_input_ties_go_to_the_earlier():
    assert metrics.nearest_input(1, [0, 2]) == 0
    assert metrics.nearest_input(3, [0, 2, 7]) == 2
    assert metrics.nearest_input(5, [0, 2, 7]) == 7
    assert metrics.nearest_input(6, [7, 0]) == 7


def test_baselines_known_values():
    """Frames of one grey value each: inputs 0 (100) and 2 (130), targets 1 (110) and 3 (120).
    Nearest input copied: target 1 -> frame 0 (a tie, the earlier), target 3 -> frame 2, both
    10 grey levels off; the inputs' mean colour (115) is 5 off for both."""
    h, w = 16, 16
    values = [100, 110, 130, 120]
    rgb = np.stack([np.full((h, w, 3), v, np.uint8) for v in values])
    dyn = np.zeros((4, h, w), bool)
    scene = Scene("s", rgb, np.zeros((4, h, w), np.int64), dyn, ["wall"])
    pred = Prediction(np.full((2, h, w, 3), 111 / 255.0), None, None, 0.1)
    acc = Accumulator(1)
    acc.add(scene, [0, 2], [1, 3], pred)
    r = acc.result(1.0)
    assert r["psnr_nearest_input"] == pytest.approx(10 * math.log10(1 / (10 / 255.0) ** 2))
    assert r["psnr_mean_colour"] == pytest.approx(10 * math.log10(1 / (5 / 255.0) ** 2))
    assert r["ssim_nearest_input"] == pytest.approx(
        np.mean([metrics.ssim_static(rgb[0] / 255.0, rgb[1] / 255.0, ~dyn[1]),
                 metrics.ssim_static(rgb[2] / 255.0, rgb[3] / 255.0, ~dyn[3])]))


# ============================================================================ end to end
SIZE = 64   # the tiny model and the scenes at 64x64 (a quarter of the pixels of 128x128)


@pytest.fixture(scope="module")
def e2e(tmp_path_factory):
    import torch
    from spar_convert.model_config import tiny
    torch.set_num_threads(1)
    d = tmp_path_factory.mktemp("eval")
    p = tool("spar-scenes", "split", "--split", "test", "--count", 2, "--size", SIZE,
             "--out", d / "scenes")
    assert p.returncode == 0, p.stderr
    cfg = d / "tiny.json"
    c = tiny()
    c.image_height = c.image_width = SIZE
    c.validate().save(str(cfg))
    ckpt = d / "tiny.pt"
    from spar_reference.cli import main as reference_main
    assert reference_main(["make-checkpoint", "--config", str(cfg), "-o", str(ckpt), "--seed", "5",
                           "--perturb", "--no-optimizer", "--threads", "1"]) == 0
    return {"dir": d, "scenes": str(d / "scenes"), "cfg": str(cfg), "ckpt": str(ckpt)}


def evaluate(e2e, **kw):
    from spar_eval.run_reference import Options, evaluate as run
    opts = Options(checkpoint=e2e["ckpt"], config=e2e["cfg"], scenes=e2e["scenes"],
                   bpe=BPE_PATH, **kw)
    return run(opts)


@pytest.fixture(scope="module")
def runs(e2e):
    return {m: evaluate(e2e, mode=m) for m in ("default", "no-gating", "assume-static")}


def check_doc(doc, mode):
    assert doc["format"] == "spar-eval" and doc["version"] == 1
    assert doc["runner"] == "reference" and doc["precision"] == "fp32" and doc["mode"] == mode
    assert doc["scenes"] == 2 and doc["frames"] == 8
    assert sorted(doc["results"]) == ["2", "3", "4"]
    for k, n in (("2", 12), ("3", 10), ("4", 8)):
        r = doc["results"][k]
        assert set(r) == set(METRIC_KEYS) | {"target_views", "seconds", "ms_per_scene"}
        assert r["target_views"] == n
        assert 0.0 < r["psnr"] < 60.0
        assert -1.0 <= r["ssim"] <= 1.0
        assert 0.0 < r["psnr_nearest_input"] < 60.0 and 0.0 < r["psnr_mean_colour"] < 60.0
        assert -1.0 <= r["ssim_nearest_input"] <= 1.0
        assert r["seconds"] > 0 and r["ms_per_scene"] > 0
        for m in ("sem_miou", "sem_accuracy"):
            assert 0.0 <= r[m] <= 1.0
        for m in ("mask_miou", "mask_iou_dynamic", "mask_recall"):
            if mode == "assume-static":
                assert r[m] is None
            else:
                assert 0.0 <= r[m] <= 1.0


def test_reference_modes(runs):
    for mode, doc in runs.items():
        check_doc(doc, mode)
    for k in ("2", "3", "4"):
        ng, st, df = (runs[m]["results"][k] for m in ("no-gating", "assume-static", "default"))
        # gating with P(dynamic) = 0 keeps every token as is: the same rendering
        for m in ("psnr", "ssim", "sem_miou", "sem_accuracy"):
            assert ng[m] == st[m], (k, m)
        # the baselines depend on the data and the views only
        for m in ("psnr_nearest_input", "ssim_nearest_input", "psnr_mean_colour"):
            assert ng[m] == st[m] == df[m], (k, m)
        # CV-DRP runs before gating: its masks do not depend on the mode
        for m in ("mask_miou", "mask_iou_dynamic", "mask_recall"):
            assert ng[m] == df[m], (k, m)


def test_reference_separate_clip_file(e2e, runs):
    """--clip: the same CLIP text weights from a separate file give the same label maps."""
    import torch
    from spar_reference.cli import load_checkpoint, split_state_dict
    _, clip_sd = split_state_dict(load_checkpoint(e2e["ckpt"]))
    path = e2e["dir"] / "clip.pt"
    torch.save({"clip": clip_sd}, path)
    doc = evaluate(e2e, mode="assume-static", views=[2], clip=str(path), max_scenes=2)
    for m in ("sem_miou", "sem_accuracy", "psnr"):
        assert doc["results"]["2"][m] == runs["assume-static"]["results"]["2"][m]


def test_cli_outputs_and_tools(e2e, runs, tmp_path):
    out = tmp_path / "r.json"
    p = tool("spar-eval-reference", "--checkpoint", e2e["ckpt"], "--config", e2e["cfg"],
             "--bpe", BPE_PATH, "--scenes", e2e["scenes"], "--views", "2", "--assume-static",
             "--max-scenes", 1, "--threads", 1, "--quiet", "--out", out)
    assert p.returncode == 0, p.stderr
    doc = json.loads(out.read_text())
    assert doc["scenes"] == 1 and doc["mode"] == "assume-static" and list(doc["results"]) == ["2"]
    assert "PSNR" in p.stdout and "assume-static" in p.stdout
    # compare: a result agrees with itself; nulls on one side or a shifted PSNR disagree
    files = {}
    for m, d in runs.items():
        files[m] = tmp_path / f"{m}.json"
        files[m].write_text(json.dumps(d))
    assert tool("spar-eval-compare", files["default"], files["default"]).returncode == 0
    assert tool("spar-eval-compare", files["no-gating"], files["assume-static"]).returncode == 1
    shifted = json.loads(json.dumps(runs["default"]))
    shifted["results"]["3"]["psnr"] += 0.01
    (tmp_path / "shifted.json").write_text(json.dumps(shifted))
    p = tool("spar-eval-compare", files["default"], tmp_path / "shifted.json")
    assert p.returncode == 1 and "K=3 psnr" in p.stdout
    assert tool("spar-eval-compare", files["default"], tmp_path / "shifted.json",
                "--tolerance", "0.02").returncode == 0
    # table: one row per file, 2 + 9 * 3 columns
    p = tool("spar-eval-table", "--row", f"tiny={files['default']}",
             "--row", f"tiny static={files['assume-static']}")
    assert p.returncode == 0, p.stderr
    rows = [l for l in p.stdout.splitlines() if l.startswith("| tiny")]
    assert len(rows) == 2 and rows[0].count("|") == 2 + 9 * 3 + 1
    assert " - | - |" in rows[1]             # assume-static: mask columns null


def eval_reference(*args):
    """spar-eval-reference ARGS through spar_eval.cli.main in this process (one torch thread):
    (exit code, stderr) as the subprocess gives them (its success runs in test_cli_outputs_and_tools)."""
    import torch
    from spar_eval.cli import main
    err = io.StringIO()
    threads = torch.get_num_threads()
    with redirect_stdout(io.StringIO()), redirect_stderr(err):
        try:
            code = main([str(a) for a in args] + ["--threads", "1"])
        except SystemExit as e:     # argparse's usage errors
            code = e.code
        finally:
            torch.set_num_threads(threads)
    return code, err.getvalue()


def test_cli_errors_leave_no_output(e2e, tmp_path):
    out = tmp_path / "r.json"
    common = ["--checkpoint", e2e["ckpt"], "--config", e2e["cfg"], "--bpe", BPE_PATH, "--out", out]
    code, err = eval_reference("--scenes", tmp_path / "missing", *common)
    assert code == 1 and err.count("\n") == 1 and "not found" in err
    code, err = eval_reference("--scenes", e2e["scenes"], "--views", "2,x", *common)
    assert code == 2 and err.count("\n") == 1
    code, err = eval_reference("--scenes", e2e["scenes"], "--views", "8", *common)
    assert code == 1 and "no target" in err
    small = tmp_path / "small"
    assert tool("spar-scenes", "split", "--split", "test", "--count", 1, "--size", SIZE // 2,
                "--out", small).returncode == 0
    code, err = eval_reference("--scenes", small, *common)
    assert code == 1 and "no resizing" in err and err.count("\n") == 1
    assert not out.exists() and not any(n.startswith("r.json") for n in os.listdir(tmp_path))
    assert tool("spar-eval-compare", tmp_path / "nope.json", tmp_path / "nope.json").returncode == 2
