#!/usr/bin/python3
"""The training batches of ``spar-train`` (training/spar_train/data.py, Sampler): targets are
the views that are not inputs (the paper's recipe), and with ``--input-targets N`` also each
scene's first N inputs (reconstruction of what the model saw).
Run: cd /work/main && /usr/bin/python3 -m pytest -q training/tests/test_train_sampler.py
"""

import os

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))

from spar_train.data import Sampler  # noqa: E402


class TinyPool:
    """Stands in for ScenePool: 5 scenes of 8 frames, 16x16."""

    def __init__(self, n=5, f=8, s=16):
        rng = np.random.default_rng(0)
        self.seeds = np.arange(n)
        self.rgb = rng.integers(0, 255, (n, f, s, s, 3), dtype=np.uint8)
        self.static_rgb = self.rgb.copy()
        self.classes = np.zeros((n, f, s, s), np.uint8)
        self.static_classes = self.classes.copy()
        self.mask = np.zeros((n, f, s, s), bool)
        self.c2w = np.tile(np.eye(4, dtype=np.float32), (n, f, 1, 1))
        self.fxfycxcy = np.tile(np.array([1, 1, 0.5, 0.5], np.float32), (n, f, 1))

    def __len__(self):
        return len(self.seeds)


def test_targets_are_the_other_views():
    s = Sampler(TinyPool(), seed=3, p_dynamic=1.0)
    for _ in range(10):
        b = s.batch(2)
        for inp, tg in zip(b["inputs"].tolist(), b["targets"].tolist()):
            assert sorted(inp + tg) == list(range(8))


def test_input_targets_add_the_first_inputs():
    plain, recon = Sampler(TinyPool(), seed=3, p_dynamic=1.0), Sampler(TinyPool(), seed=3, p_dynamic=1.0,
                                                                         input_targets=1)
    for _ in range(10):
        a, b = plain.batch(2), recon.batch(2)
        assert a["inputs"].tolist() == b["inputs"].tolist()  # the same draws
        for inp, tg, tg_plain in zip(b["inputs"].tolist(), b["targets"].tolist(), a["targets"].tolist()):
            assert sorted(tg) == tg
            assert set(tg) == set(tg_plain) | {inp[0]}


def test_batches_converted_on_a_device_equal_the_cpu_ones():
    """Sampler(device=...) converts the bytes to floats where the model trains (a GPU run);
    the values and the draws are the same as converting on the CPU (here: device "cpu")."""
    import torch
    pool = TinyPool()
    pool.mask[1, 2, 3:6, 4:9] = True           # something to paste
    plain, placed = Sampler(pool, seed=5), Sampler(pool, seed=5, device=torch.device("cpu"))
    kinds = set()
    for _ in range(12):
        a, b = plain.batch(2), placed.batch(2)
        kinds.add(a["kind"])
        assert a["kind"] == b["kind"]
        for k in ("images", "clean", "paste", "inputs", "targets", "c2w", "fxfycxcy"):
            assert a[k].dtype == b[k].dtype and torch.equal(a[k], b[k]), k
        assert a["images"].dtype == torch.float32 and float(a["images"].max()) <= 1.0
    assert kinds == {"dynamic", "static", "copy-paste"}
