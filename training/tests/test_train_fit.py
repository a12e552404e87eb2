#!/usr/bin/python3
"""A model fitted to the shipped rooms (``spar-train --fit-scenes samples/data/scenes``) trains
on other takes of those rooms, never on their own frames: its scene pool (training/spar_train/
data.py, ScenePool with fit_seeds) is compared frame by frame with the shipped scenes.
Run: cd /work/main && /usr/bin/python3 -m pytest -q training/tests/test_train_fit.py
"""

import json
import os

import numpy as np
import pytest
from PIL import Image

HERE = os.path.dirname(os.path.abspath(__file__))
SHIPPED = os.path.join(HERE, "..", "..", "samples", "data", "scenes")

from spar_train.data import ScenePool  # noqa: E402
from spar_train.fit import fit_jobs, fit_seeds  # noqa: E402


def shipped_frames():
    with open(os.path.join(SHIPPED, "index.json")) as f:
        index = json.load(f)
    return np.stack([np.asarray(Image.open(os.path.join(SHIPPED, sc["path"], "rgb_%02d.png" % i)).convert("RGB"))
                     for sc in index["scenes"] for i in range(index["frames"])])


def test_fit_jobs_are_takes_of_the_folders_rooms_only():
    seeds = fit_seeds(SHIPPED)
    assert seeds == [1000000, 1000001, 1000002]
    jobs = fit_jobs(seeds, 400)
    assert len(set(jobs)) == 400 and {s for s, _ in jobs} == set(seeds)
    assert min(t for _, t in jobs) == 1                     # take 0 is the shipped scene itself


def test_fitted_pool_holds_none_of_the_shipped_frames(tmp_path):
    """A take of each room as spar-train renders them (8 frames at 128 px, with and without
    movers): no frame is within 4 grey levels (mean absolute difference) of any of the 24
    shipped frames (the closest measured: 19)."""
    pool = ScenePool(3, 8, 128, str(tmp_path), workers=1, log=lambda m: None, fit_seeds=fit_seeds(SHIPPED))
    assert sorted(set(pool.seeds.tolist())) == [1000000, 1000001, 1000002] and pool.takes.min() >= 1
    shipped = shipped_frames().astype(np.float32)
    for frames in (pool.rgb, pool.static_rgb):
        f = frames.reshape(-1, *frames.shape[2:]).astype(np.float32)
        diff = np.abs(f[:, None] - shipped[None]).mean(axis=(2, 3, 4))   # [pool frames, 24]
        assert diff.min() > 4.0, diff.min()


def test_fit_scenes_folder_without_index_is_refused(tmp_path):
    with pytest.raises(ValueError, match="not a spar-scenes folder"):
        fit_seeds(str(tmp_path))


def test_fitted_card_says_what_the_model_was_fitted_to(tmp_path):
    """The card fit-rooms.sh packs: the converter's checker takes it; it names the rooms, the
    steps and minutes of the run's last curve point, and spar eval's K=3 PSNR and copy baseline."""
    from spar_convert.model_card import check_card
    from spar_train.fitted_card import fitted_card
    curve = tmp_path / "curve.jsonl"
    curve.write_text('{"step": 0, "minutes": 0.0}\n{"step": 2200, "minutes": 77.04}\n')
    result = tmp_path / "eval.json"
    result.write_text(json.dumps({"results": {"3": {"psnr": 24.567, "psnr_nearest_input": 20.0169}}}))
    card = check_card(fitted_card(str(curve), str(result), SHIPPED, 400), "card")
    assert "seeds 1000000, 1000001, 1000002" in card["about"] and "never their own frames" in card["about"]
    assert card["measured"]["psnr_db"] == 24.57 and card["measured"]["baseline_psnr_db"] == 20.02
    assert card["training"]["steps"] == 2200 and card["training"]["minutes"] == 77.0
    assert card["training"]["data"].startswith("400 takes of the 3 rooms")
