"""`import spar` (python/spar_module.cpp): the Python path gives the bytes `spar render` gives,
every bad argument is a spar.Error, device work releases the GIL, and two sessions on one
context run from two threads. Run by CTest (py_spar_module) with PYTHONPATH=build/python and
SPAR_CLI=the built spar; the validation layer on (its message count is checked)."""
import json
import os
import subprocess
import threading
import time

import numpy as np
import pytest

import spar

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SHIPPED = os.path.join(ROOT, "data", "spar_rooms.spar")
SCENE = os.path.join(ROOT, "data", "scenes", "scene_1000002")
SELFTEST = os.path.join(ROOT, "data", "selftest")  # a small model with the semantic branch
FRAMES = [os.path.join(SCENE, "rgb_0%d.png" % i) for i in (0, 2, 4, 7)]
LABELS = ["wall", "floor", "sofa", "window"]


@pytest.fixture(scope="module")
def ctx():
    c = spar.Context(validation=True)
    yield c
    assert c.validation_messages == 0


@pytest.fixture(scope="module")
def shipped():
    return spar.Model.open(SHIPPED)


@pytest.fixture(scope="module")
def small():
    return spar.Model.open(os.path.join(SELFTEST, "model.spar")), np.load(os.path.join(SELFTEST, "images.npy"))


def test_demonstration_note(shipped, small):
    """What the model file says it is: the shipped model's card, the same sentence spar render prints."""
    note = shipped.demonstration_note
    assert note.startswith("Demonstration model: ") and "PSNR 21.0 dB, above the 20.0 dB" in note, note
    assert note.endswith("; for real photos, convert the official checkpoint (docs/checkpoints.md).")
    assert small[0].demonstration_note == ""


def test_same_bytes_and_labels_as_spar_render(ctx, shipped, tmp_path):
    out = tmp_path / "cli"
    subprocess.run([os.environ["SPAR_CLI"], "render", "--model", SHIPPED, "--frames", *FRAMES, "--inputs", "0,2,3",
                    "--labels", ",".join(LABELS), "--out", str(out)], check=True, capture_output=True)
    h, w = shipped.image_size
    images = np.stack([spar.load_image(f, h, w) for f in FRAMES])
    assert images.shape == (4, 3, h, w) and images.dtype == np.float32
    with spar.Session(ctx, shipped) as s:
        enc = s.encode(images, inputs=[0, 2, 3], semantic_features=True)
        assert enc["c2w"].shape == (4, 4, 4) and enc["motion_input"].shape == (3, h, w)
        rgb = s.render_targets()
        assert rgb.shape == (1, 3, h, w)
        spar.write_png(str(tmp_path / "view.png"), rgb[0])
        assert (tmp_path / "view.png").read_bytes() == (out / "view_00.png").read_bytes()
        # the label maps: the shares the CLI reports, to its rounding
        maps = s.label_maps(LABELS)
        assert maps.shape == (1, h, w) and maps.dtype == np.int32
        shares = np.bincount(maps.ravel(), minlength=len(LABELS)) / maps.size
        cli = {l["label"]: l["share"] for l in json.load(open(out / "labels_00.json"))["labels"]}
        for i, label in enumerate(LABELS):
            assert abs(shares[i] - cli[label]) < 1e-3, (label, shares[i], cli[label])
        feats = s.features()
        assert feats.shape[0] == 1 and feats.shape[2:] == (h // 2, w // 2)
        # a path through the input cameras, as --path makes it
        c2w, k = spar.path_cameras(enc, [0, 2, 3], 3)
        assert c2w.shape == (3, 4, 4) and k.shape == (3, 4)
        assert s.render(c2w, k).shape == (3, 3, h, w)
        names = [t["name"] for t in s.stage_times()]
        assert "renderer" in names and "cv_drp" in names


def test_the_options_spar_render_uses(ctx, small, tmp_path):
    """What the CLI takes from the library, from Python too: precisions, the memory estimate and its
    refusal before any work, label scores, the kernel report, the device and kept intermediates."""
    model, images = small
    assert spar.precisions() == ["fp32", "fp16", "q8", "q4"]
    assert model.size_problem(*model.image_size) == ""
    assert "not a multiple" in model.size_problem(17, 17)
    views = images.shape[0]
    with spar.Session(ctx, model, precision="q8", keep_intermediates=True) as s:
        need = s.estimate_memory(views, [0, 2], semantic_features=True, label_prompts=2)
        assert 0 < need["weight_bytes"] < need["min_bytes"] <= need["max_bytes"] and need["refusal"] == ""
        s.encode(images, inputs=[0, 2], semantic_features=True)
        s.render_targets()
        maps, scores = s.label_maps(LABELS[:2], scores=True)
        h, w = model.image_size
        assert maps.shape == (views - 2, h, w) and scores.shape == (views - 2, 2, h // 2, w // 2)
        # the label maps are the argmax of the scores enlarged x2 (bilinear, align_corners):
        # recomputed here, they agree wherever the two prompts are not within rounding of a tie
        def enlarge(x):
            n = x.shape[-1]
            at = np.arange(2 * n) * (n - 1) / (2 * n - 1)
            lo = np.minimum(np.floor(at).astype(int), n - 2)
            f = at - lo
            x = x[..., lo, :] * (1 - f)[:, None] + x[..., lo + 1, :] * f[:, None]
            return x[..., lo] * (1 - f) + x[..., lo + 1] * f
        lead = enlarge(scores[:, 0] - scores[:, 1])
        clear = np.abs(lead) > 1e-3
        assert clear.mean() > 0.9 and np.all((maps[clear] == 0) == (lead[clear] > 0))
        assert "c2w" in s.intermediate_names() and s.intermediate("c2w").shape == (views, 4, 4)
        assert s.weight_bytes_loaded > 0
        names = [t["name"] for t in s.stage_times()]
        assert "renderer" in names and names[-2:] == ["text_encoder", "labels"], names
    report = ctx.kernel_report()
    assert report["pipelines"] > 0 and report["plan"] and report["kernels"][0]["name"]
    assert ctx.device["name"] == ctx.device_name and ctx.memory()["peak_bytes"] > 0


def test_memory_refusal_before_any_work(small):
    """A request above the device's memory budget is refused by encode itself, before any work
    (no device buffer allocated), with the estimate's one line."""
    model, images = small
    os.environ["SPAR_MEMORY_LIMIT_MB"] = "1"
    try:
        c = spar.Context(validation=True)
    finally:
        del os.environ["SPAR_MEMORY_LIMIT_MB"]
    with spar.Session(c, model) as s:
        need = s.estimate_memory(images.shape[0], [0, 2])
        assert need["budget_bytes"] == 1 << 20 and need["refusal"].startswith("this request needs at least")
        before = c.memory()["allocations"]
        with pytest.raises(spar.Error, match="needs at least .* MiB of device memory"):
            s.encode(images, inputs=[0, 2])
        assert c.memory()["allocations"] == before
    assert c.validation_messages == 0


def test_bad_arguments_are_spar_errors(ctx, small):
    model, images = small
    with pytest.raises(spar.Error, match="no such file|cannot|not found"):
        spar.Model.open("/nonexistent/model.spar")
    s = spar.Session(ctx, model)
    cases = {
        "dtype float64, expected float32": lambda: s.encode(images.astype(np.float64)),
        "shape": lambda: s.encode(images.transpose(0, 2, 3, 1).copy()),
        "NaN or infinite": lambda: s.encode(np.where(np.arange(images.size).reshape(images.shape) == 7, np.nan,
                                                     images).astype(np.float32)),
        "NumPy float32 array": lambda: s.encode([[1.0, 2.0]]),
        "outside the sequence": lambda: s.encode(images, inputs=[0, 9]),
    }
    for message, call in cases.items():
        with pytest.raises(spar.Error, match=message):
            call()
    s.encode(images, inputs=[0, 2, 4])
    with pytest.raises(spar.Error, match="c2w: shape"):
        s.render(np.zeros((2, 3, 4), np.float32), np.zeros((2, 4), np.float32))
    # this encode asked for no semantic features, so there is nothing to label
    s.render_targets()
    with pytest.raises(spar.Error, match="asked for semanticFeatures"):
        s.label_maps(["wall"])
    s.close()
    # a model without the semantic branch has no label maps to give, whatever the request
    photometric = spar.Session(ctx, spar.Model.open(os.environ["SPAR_PHOTOMETRIC_MODEL"]))
    photometric.encode(images, inputs=[0, 2, 4])
    photometric.render_targets()
    with pytest.raises(spar.Error, match="semantic branch"):
        photometric.label_maps(["wall"])
    photometric.close()
    with pytest.raises(spar.Error, match="closed"):
        s.render_targets()
    with pytest.raises(spar.Error, match="closed"):
        s.encode(images)
    # one line each
    try:
        spar.Model.open("/nonexistent/model.spar")
    except spar.Error as e:
        assert "\n" not in str(e)


def test_sam2_refinement(ctx):
    """refine / mask_source / refine_prompts: the refined masks and what SAM2 decided per view."""
    model = spar.Model.open(os.environ["SPAR_SAM2_MODEL"])  # the tiny model with a tiny SAM2.1
    h, w = model.image_size
    rng = np.random.default_rng(5)
    images = rng.random((3, 3, h, w), dtype=np.float32)
    prompts = np.full((3, h, w), 0.1, np.float32)
    prompts[0, 30:80, 40:90] = 0.9  # view 0: a block (refined); view 2: nothing (skipped)
    with spar.Session(ctx, model) as s:
        plain = s.encode(images, inputs=[0, 2], targets=[1])
        assert "refined_input" not in plain
        e = s.encode(images, inputs=[0, 2], targets=[1], refine=True, refine_prompts=prompts)
        assert e["refined_input"].shape == (2, h, w) and e["refined_target"] is None
        assert set(np.unique(e["refined_input"])) <= {0.0, 1.0}
        views = e["refine_views"]
        assert [v["view"] for v in views] == [0, 2] and [v["skipped"] for v in views] == [False, True]
        assert views[0]["logits"].shape == (256, 256) and len(views[0]["iou"]) == 3 and views[1]["iou"] is None
        # the mask is what its logits say, resized (> 0) and > 0 where SAM2 chose
        assert e["refined_input"][0].sum() > 0 and e["refined_input"][1].sum() == 0
        gated = s.encode(images, inputs=[0, 2], targets=[1], mask_source="refined", refine_prompts=prompts)
        np.testing.assert_array_equal(gated["refined_input"], e["refined_input"])
        with pytest.raises(spar.Error, match="mask_source must be"):
            s.encode(images, inputs=[0, 2], mask_source="sam2")
        with pytest.raises(spar.Error, match="mask_source must be"):
            s.estimate_memory(images.shape[0], [0, 2], mask_source="sam2")
        with pytest.raises(spar.Error, match="refine_prompts: shape"):
            s.encode(images, inputs=[0, 2], refine=True, refine_prompts=prompts[:2])
    photometric = spar.Session(ctx, spar.Model.open(os.environ["SPAR_PHOTOMETRIC_MODEL"]))
    with pytest.raises(spar.Error, match="no SAM2.1 weights"):
        photometric.encode(images[:, :, :128, :128], inputs=[0, 2], refine=True)
    photometric.close()


def test_device_work_releases_the_gil(ctx, small):
    model, images = small
    counted = [0]
    stop = threading.Event()

    def count():
        while not stop.is_set():
            counted[0] += 1

    with spar.Session(ctx, model) as s:
        s.encode(images)  # kernels built once: the timed call below is device work alone
        t = threading.Thread(target=count)
        t.start()
        time.sleep(0.05)
        before = counted[0]
        start = time.perf_counter()
        for _ in range(3):
            s.encode(images)
            s.render_targets()
        seconds = time.perf_counter() - start
        during = counted[0] - before
        stop.set()
        t.join()
    # Holding the GIL through the calls would leave the counter still (a few switches at most).
    assert during > 1000, (during, seconds)


def test_two_threads_two_sessions_one_context(ctx, small):
    model, images = small
    want = {}
    for inputs in ([0, 2, 4], [1, 3]):
        with spar.Session(ctx, model) as s:
            s.encode(images, inputs=inputs)
            want[tuple(inputs)] = s.render_targets()
    got, errors = {}, []

    def run(inputs):
        try:
            with spar.Session(ctx, model) as s:
                for _ in range(3):
                    s.encode(images, inputs=inputs)
                    got[tuple(inputs)] = s.render_targets()
        except Exception as e:  # reported below, not lost in the thread
            errors.append(e)

    threads = [threading.Thread(target=run, args=(inputs,)) for inputs in ([0, 2, 4], [1, 3])]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    for key, rgb in want.items():
        assert np.array_equal(got[key], rgb), key


def test_cameras_file_and_help():
    doc = spar.Session.__doc__ + spar.Session.encode.__doc__
    assert "encode" in doc and "(V, 3, H, W)" in doc and "motion_input" in doc
    assert "spar.Error" in spar.__doc__
    with pytest.raises(spar.Error, match="cameras file not found"):
        spar.read_cameras("/nonexistent/transforms.json", 64, 64)


def test_example_script_runs(tmp_path):
    r = subprocess.run(["/usr/bin/python3", os.path.join(ROOT, "examples", "python", "render_scene.py"), str(tmp_path)],
                       capture_output=True, text=True, env=dict(os.environ), timeout=240)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["path_%02d.png" % i for i in range(8)]
    assert "labels: wall" in r.stdout


def test_video_frames_as_spar_render_takes_them(ctx, shipped):
    video = "/usr/share/doc/opencv-doc/examples/data/vtest.avi"
    h, w = shipped.image_size
    frames, times = spar.load_video(video, h, w, count=4)
    assert frames.shape == (4, 3, h, w) and frames.dtype == np.float32
    assert np.allclose(times, [d * 79.5 / 8 for d in (1, 3, 5, 7)], atol=0.05), times
    assert 0.0 <= frames.min() and frames.max() <= 1.0 and frames.std() > 0.05
    at, t2 = spar.load_video(video, h, w, at=[62.0, 62.4])
    assert at.shape == (2, 3, h, w) and list(t2) == [62.0, 62.4]
    with spar.Session(ctx, shipped) as s:
        enc = s.encode(frames, inputs=[0, 3])
        assert np.isfinite(enc["c2w"]).all() and s.render_targets().shape == (2, 3, h, w)
    with pytest.raises(spar.Error, match="no frame at 90.000 s"):
        spar.load_video(video, h, w, at=[90.0])
    with pytest.raises(spar.Error, match="video not found"):
        spar.load_video("/nonexistent.mp4", h, w)
