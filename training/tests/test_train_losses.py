#!/usr/bin/python3
"""The camera loss of ``spar-train --pose-loss`` (training/spar_train/losses.py): zero for the
true cameras at any scale of the positions (the model's scale is its own), positive for a wrong
rotation, position or intrinsics, and differentiable through the prediction.
Run: cd /work/main && /usr/bin/python3 -m pytest -q training/tests/test_train_losses.py
"""

import math
import os

import pytest
import torch

HERE = os.path.dirname(os.path.abspath(__file__))

from spar_train.losses import camera_loss  # noqa: E402


def cameras(b=2, v=4, seed=0):
    g = torch.Generator().manual_seed(seed)
    c2w = torch.eye(4).repeat(b, v, 1, 1)
    for i in range(b):
        for j in range(v):
            a = float(torch.rand(1, generator=g)) * math.pi
            c, s = math.cos(a), math.sin(a)
            c2w[i, j, :3, :3] = torch.tensor([[c, 0, s], [0, 1, 0], [-s, 0, c]])
            c2w[i, j, :3, 3] = torch.randn(3, generator=g)
    k = torch.tensor([1.1, 1.1, 0.5, 0.5]).repeat(b, v, 1)
    return c2w, k


def test_true_cameras_at_any_scale_cost_nothing():
    c2w, k = cameras()
    assert float(camera_loss(c2w, k, c2w, k)) == pytest.approx(0.0, abs=1e-10)
    scaled = c2w.clone()
    scaled[..., :3, 3] *= 3.7
    assert float(camera_loss(scaled, k, c2w, k)) == pytest.approx(0.0, abs=1e-10)


def test_wrong_rotation_position_or_intrinsics_cost():
    c2w, k = cameras()
    rot = c2w.clone()
    rot[0, 1, :3, :3] = rot[0, 1, :3, :3].flip(0)
    pos = c2w.clone()
    pos[1, 2, :3, 3] += torch.tensor([0.5, 0.0, 0.0])
    wrong_k = k.clone()
    wrong_k[..., 0] += 0.1
    for pred, kk in ((rot, k), (pos, k), (c2w, wrong_k)):
        assert float(camera_loss(pred, kk, c2w, k)) > 1e-4


def test_gradient_reaches_the_prediction():
    c2w, k = cameras()
    pred = (c2w + 0.01 * torch.randn_like(c2w)).requires_grad_(True)
    camera_loss(pred, k, c2w, k).backward()
    assert pred.grad is not None and float(pred.grad.abs().sum()) > 0
