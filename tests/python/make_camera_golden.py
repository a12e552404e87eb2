#!/usr/bin/python3
"""Goldens for tests/test_plucker_rays.cpp: the reference's camera functions in float64.

Inputs are random, rounded to float32 (the engine's values), and the reference
(reference/spar_reference/spar.py) runs in float64 on exactly those values. Writes into --out,
one directory per case:

  rays cases (plucker_rays(c2w, fxfycxcy, H, W, normalized=True)):
    c2w.npy [V,4,4] '<f4', k.npy [V,4] '<f4', rays.npy [V,6,H,W] '<f8'
    random        V=3, H=37, W=61: random rotations (rot6d_to_mat of random 6D), t ~ N(0, 2^2),
                  fx, fy in [0.5, 2], cx, cy in [0.3, 0.7]
    focal_small   as random with fx = fy = 1e-3
    focal_large   as random with fx = fy = 1e3
    zero_t        as random with t = 0 (o x d = 0)
    identical     3 copies of one camera (identical rays)
  pose cases (PoseEstimator.forward with its heads' outputs given, then cam_info_to_se3):
    rel.npy [B,V-1,9] '<f4', kraw.npy [B,1] '<f4', c2w.npy [B,V,4,4] '<f8', k.npy [B,V,4] '<f8'
    pose_random     B=2, V=5 (canonical 2): rel ~ N(0, 0.5^2), kraw ~ N(0, 0.1^2)
    pose_even       B=3, V=4 (canonical 2)
    pose_collinear  B=2, V=7: a2 = c a1 + 1e-5 |a1| n (nearly collinear 6D vectors)
    pose_single     B=2, V=1 (canonical only, no rel)

Usage: make_camera_golden.py --out DIR [--seed S]
"""

import argparse
import os

import numpy as np
import torch

from spar_reference.config import tiny  # noqa: E402
from spar_reference.spar import PoseEstimator, cam_info_to_se3, plucker_rays, rot6d_to_mat  # noqa: E402

H, W = 37, 61


def f32(x: torch.Tensor) -> torch.Tensor:
    return x.to(torch.float32).to(torch.float64)


def save(d: str, name: str, x: torch.Tensor, dtype: str) -> None:
    np.save(os.path.join(d, name + ".npy"), x.detach().numpy().astype(dtype))


def random_cameras(v: int, gen: torch.Generator):
    r = rot6d_to_mat(torch.randn(v, 6, generator=gen, dtype=torch.float64))
    c2w = torch.zeros(v, 4, 4, dtype=torch.float64)
    c2w[:, :3, :3] = r
    c2w[:, :3, 3] = torch.randn(v, 3, generator=gen, dtype=torch.float64) * 2
    c2w[:, 3, 3] = 1
    k = torch.empty(v, 4, dtype=torch.float64)
    k[:, :2] = torch.rand(v, 2, generator=gen, dtype=torch.float64) * 1.5 + 0.5
    k[:, 2:] = torch.rand(v, 2, generator=gen, dtype=torch.float64) * 0.4 + 0.3
    return c2w, k


def ray_case(out: str, name: str, c2w: torch.Tensor, k: torch.Tensor) -> None:
    d = os.path.join(out, name)
    os.makedirs(d, exist_ok=True)
    c2w, k = f32(c2w), f32(k)
    rays = plucker_rays(c2w, k, H, W, normalized=True)
    save(d, "c2w", c2w, "<f4")
    save(d, "k", k, "<f4")
    save(d, "rays", rays, "<f8")


class Given(torch.nn.Module):
    """Stands in for a head: returns the given outputs (checks the input's leading shape)."""

    def __init__(self, y: torch.Tensor):
        super().__init__()
        self.y = y

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        assert x.shape[:-1] == self.y.shape[:-1], (x.shape, self.y.shape)
        return self.y


def pose_case(out: str, name: str, rel: torch.Tensor, kraw: torch.Tensor, v: int) -> None:
    d = os.path.join(out, name)
    os.makedirs(d, exist_ok=True)
    b = kraw.shape[0]
    rel, kraw = f32(rel), f32(kraw)
    est = PoseEstimator(tiny()).to(torch.float64)
    est.rel_head = Given(rel)
    est.canonical_k_head = Given(kraw)
    x = torch.zeros(b, v, tiny().d, dtype=torch.float64)  # camera tokens: unused by the given heads
    with torch.no_grad():
        cam_info = est(x)
        c2w, k = cam_info_to_se3(cam_info.reshape(b * v, -1))
    save(d, "rel", rel, "<f4")
    save(d, "kraw", kraw, "<f4")
    save(d, "c2w", c2w.reshape(b, v, 4, 4), "<f8")
    save(d, "k", k.reshape(b, v, 4), "<f8")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=4321)
    args = ap.parse_args(argv)
    gen = torch.Generator().manual_seed(args.seed)

    c2w, k = random_cameras(3, gen)
    ray_case(args.out, "random", c2w, k)
    c2w, k = random_cameras(3, gen)
    k[:, :2] = 1e-3
    ray_case(args.out, "focal_small", c2w, k)
    c2w, k = random_cameras(3, gen)
    k[:, :2] = 1e3
    ray_case(args.out, "focal_large", c2w, k)
    c2w, k = random_cameras(3, gen)
    c2w[:, :3, 3] = 0
    ray_case(args.out, "zero_t", c2w, k)
    c2w, k = random_cameras(1, gen)
    ray_case(args.out, "identical", c2w.repeat(3, 1, 1), k.repeat(3, 1))

    def randn(*s):
        return torch.randn(*s, generator=gen, dtype=torch.float64)

    pose_case(args.out, "pose_random", randn(2, 4, 9) * 0.5, randn(2, 1) * 0.1, 5)
    pose_case(args.out, "pose_even", randn(3, 3, 9) * 0.5, randn(3, 1) * 0.1, 4)
    # Nearly collinear 6D vectors: a2 = c a1 + 1e-5 |a1| n, given as rel = a - identity offset.
    a1 = randn(2, 6, 3)
    c = randn(2, 6, 1)
    a2 = c * a1 + 1e-5 * a1.norm(dim=-1, keepdim=True) * randn(2, 6, 3)
    rel = torch.cat([a1, a2, randn(2, 6, 3)], dim=-1)
    rel = rel - torch.tensor([1, 0, 0, 0, 1, 0, 0, 0, 0], dtype=torch.float64)
    pose_case(args.out, "pose_collinear", rel, randn(2, 1) * 0.1, 7)
    pose_case(args.out, "pose_single", torch.zeros(2, 0, 9, dtype=torch.float64), randn(2, 1) * 0.1, 1)


if __name__ == "__main__":
    main()
