#!/usr/bin/python3
"""A model fitted to the shipped rooms (``spar-train --fit-scenes data/scenes``) trains
on other takes of those rooms, never on their own frames: its scene pool (training/spar_train/
data.py, ScenePool with fit_seeds) is compared frame by frame with the shipped scenes.
Also: ``--init-from`` of the shipped model unpacks and packs back to the same tensors.
Run: cd /work/main && /usr/bin/python3 -m pytest -q training/tests/test_train_fit.py
"""

import json
import os

import numpy as np
import pytest
from PIL import Image

HERE = os.path.dirname(os.path.abspath(__file__))
SHIPPED = os.path.join(HERE, "..", "..", "data", "scenes")

from spar_train.data import ScenePool  # noqa: E402
from spar_train.fit import fit_jobs, fit_seeds  # noqa: E402

import torch  # noqa: E402

from spar_convert.convert import main as convert_main  # noqa: E402
from spar_convert.safetensors_file import SafetensorsFile  # noqa: E402
from spar_reference import dino_v3, lseg as lseg_mod  # noqa: E402
from spar_reference.cli import add_clip_text  # noqa: E402
from spar_reference.clip_text import CLIPTextEncoder  # noqa: E402
from spar_reference.spar import SPAR  # noqa: E402
from spar_train import init_from  # noqa: E402
from spar_train.config import small_config  # noqa: E402

SHIPPED_MODEL = os.path.join(HERE, "..", "..", "data", "spar_rooms.spar")
BPE = os.path.join(HERE, "..", "..", "text", "data", "clip", "bpe_simple_vocab_16e6.txt.gz")


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


# ``spar-train --init-from MODEL.spar`` (spar_train/init_from.py): the shipped general model
# unpacked into the training model, its converter folds undone, packed again by spar-convert,
# gives the shipped file's tensors back (the folds, with frozen BatchNorms, are the identity
# they were). The learning curve's step 0 measures it too: 21.00 dB on the shipped scenes, what
# `spar eval` gives the shipped model (training/README.md).
def shipped_model():
    cfg = small_config(128, 64)
    model = SPAR(cfg, dino=dino_v3.DinoV3(cfg.dino, seed=11), lseg=lseg_mod.LSegEncoder(cfg.lseg)).float()
    init_from.load_into(model, SHIPPED_MODEL, log=lambda *_: None)
    return cfg, model


def test_unpacked_model_packs_back_to_the_shipped_file(tmp_path):
    cfg, model = shipped_model()
    text = CLIPTextEncoder(cfg.clip).float()
    text.load_state_dict(init_from.text_encoder_state(SHIPPED_MODEL))
    ck = {"model": model.state_dict()}
    add_clip_text(ck, cfg, 0, False, encoder=text)
    torch.save(ck, tmp_path / "checkpoint.pt")
    (tmp_path / "config.json").write_text(json.dumps(cfg.to_dict()))
    out = tmp_path / "again.spar"
    assert convert_main(["-q", str(tmp_path / "checkpoint.pt"), "--config", str(tmp_path / "config.json"),
                         "--bpe", BPE, "--fp16", "-o", str(out)]) == 0
    with SafetensorsFile(SHIPPED_MODEL) as a, SafetensorsFile(str(out)) as b:
        assert sorted(a.names) == sorted(b.names)
        folded = json.loads(a.metadata["conversion"])["folded"]
        for name in a.names:
            x, y = np.asarray(a[name]), np.asarray(b[name])
            assert x.dtype == y.dtype and x.shape == y.shape, name
            if name in folded:   # folded again in float64 from (1 - eps) + eps: one fp16 step at most
                spacing = np.spacing(np.abs(x).astype(np.float16)).astype(np.float32)
                assert np.all(np.abs(x.astype(np.float32) - y.astype(np.float32)) <= spacing), name
            else:
                assert np.array_equal(x, y), name


def test_batch_norms_stay_identities_while_training():
    _, model = shipped_model()
    model.train()
    init_from.freeze_batch_norms(model)
    assert not any(m.training for m in model.modules() if isinstance(m, torch.nn.modules.batchnorm._BatchNorm))
    _, unfolded = init_from.unpack(SHIPPED_MODEL)
    bns = [model.get_submodule(name.rstrip(".")) for name in unfolded]
    assert len(bns) == 22   # CV-DRP's DPT decoder 8, LSeg's RefineNet 14
    with torch.no_grad():   # each adds its bias (the fold's, where the convolution has none), no more
        for bn in bns:
            x = torch.randn(2, bn.num_features, 5, 7)
            assert torch.allclose(bn(x), x + bn.bias[None, :, None, None], atol=1e-6, rtol=1e-6)


def test_a_file_of_another_configuration_is_one_line(tmp_path):
    cfg = small_config(128, 192)   # 192 scene tokens: the shipped file has 64
    model = SPAR(cfg, dino=dino_v3.DinoV3(cfg.dino, seed=11), lseg=lseg_mod.LSegEncoder(cfg.lseg)).float()
    with pytest.raises(init_from.InitFromError, match="another configuration"):
        init_from.load_into(model, SHIPPED_MODEL, log=lambda *_: None)
    bad = tmp_path / "bad.spar"
    bad.write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{}")
    with pytest.raises(init_from.InitFromError, match="bad.spar"):
        init_from.unpack(str(bad))
