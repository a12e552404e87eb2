"""Training scenes: a pool of procedural rooms (spar_scenes, train seeds) rendered once and
cached, and the three kinds of samples the paper trains on: dynamic scenes (people and pets
walk through), static scenes, and static scenes with copy-paste distractors (cut-outs of
another scene's distractors pasted frame by frame; the pasted mask is the only motion
supervision, as in the paper)."""
import os
import time
from multiprocessing import Pool

import numpy as np
import torch

from spar_scenes import copy_paste, generate_scene, split_seeds

from .fit import fit_jobs


def _render(args):
    seed, take, frames, size = args
    dyn = generate_scene(seed, n_frames=frames, size=size, distractors=True, take=take)
    sta = generate_scene(seed, n_frames=frames, size=size, distractors=False, take=take)
    # cameras: the same for both renderings of the room (canonical view F // 2, normalized K)
    return (seed, dyn["rgb"], dyn["classes"], dyn["mask"], sta["rgb"], sta["classes"],
            dyn["c2w_canonical"].astype(np.float32), dyn["fxfycxcy"].astype(np.float32))


class ScenePool:
    """Scenes of train seeds 0..count-1: per scene the dynamic frames (rgb, classes, motion
    mask), the same room without distractors (rgb, classes), and the frames' true cameras
    (c2w relative to the canonical view F // 2, normalized intrinsics) for the camera loss.
    ``fit_seeds``: instead, ``count`` takes of those rooms (fit_jobs: other camera arcs and
    moments of the same rooms and movers, spar_scenes.generate_scene's ``take``), for a model
    fitted to them."""

    def __init__(self, count: int, frames: int, size: int, cache_dir: str, workers: int = 2,
                 log=print, fit_seeds=None):
        fit = "" if not fit_seeds else "fit" + "-".join(str(int(s)) for s in fit_seeds) + "_"
        path = os.path.join(cache_dir, f"pool_{fit}{count}x{frames}_{size}_cams.npz")
        if os.path.isfile(path):
            z = np.load(path)
            self.seeds, self.rgb, self.classes = z["seeds"], z["rgb"], z["classes"]
            self.mask, self.static_rgb, self.static_classes = z["mask"], z["static_rgb"], z["static_classes"]
            self.c2w, self.fxfycxcy = z["c2w"], z["fxfycxcy"]
            # (pools cached before takes existed are all take 0)
            self.takes = z["takes"] if "takes" in z.files else np.zeros(len(self.seeds), np.int64)
            log(f"scene pool: {count} scenes from {path}")
            return
        t0 = time.time()
        pairs = fit_jobs(fit_seeds, count) if fit_seeds else [(int(s), 0) for s in split_seeds("train", count)]
        jobs = [(seed, take, frames, size) for seed, take in pairs]
        with Pool(workers) as p:
            res = []
            for i, r in enumerate(p.imap(_render, jobs, chunksize=4)):
                res.append(r)
                if (i + 1) % 50 == 0 or i + 1 == count:
                    log(f"scene pool: rendered {i + 1}/{count} scenes ({time.time() - t0:.0f} s)")
        self.seeds = np.array([r[0] for r in res])
        self.takes = np.array([take for _, take in pairs])
        self.rgb = np.stack([r[1] for r in res])
        self.classes = np.stack([r[2] for r in res])
        self.mask = np.stack([r[3] for r in res])
        self.static_rgb = np.stack([r[4] for r in res])
        self.static_classes = np.stack([r[5] for r in res])
        self.c2w = np.stack([r[6] for r in res])
        self.fxfycxcy = np.stack([r[7] for r in res])
        os.makedirs(cache_dir, exist_ok=True)
        tmp = path + ".tmp.npz"
        np.savez(tmp, seeds=self.seeds, rgb=self.rgb, classes=self.classes, mask=self.mask,
                 static_rgb=self.static_rgb, static_classes=self.static_classes, c2w=self.c2w,
                 fxfycxcy=self.fxfycxcy, takes=self.takes)
        os.replace(tmp, path)

    def __len__(self):
        return len(self.seeds)


def to_tensor(rgb_u8: np.ndarray, device=None) -> torch.Tensor:
    """[..., H, W, 3] uint8 -> [..., 3, H, W] float in [0, 1], on `device` (default the CPU).
    The bytes travel and are converted there: a batch of 32 scenes is 12.6 MB of bytes but
    50 MB of floats, whose conversion alone took a CPU core about 0.2 s. Same values anywhere."""
    t = _on(torch.from_numpy(np.ascontiguousarray(rgb_u8)), device)
    return (t.float() / 255.0).movedim(-1, -3)


def _on(t: torch.Tensor, device) -> torch.Tensor:
    return t if device is None else t.to(device)


class Sampler:
    """Draws training batches. Each batch is one kind (as the official training draws a batch
    from one dataset): 'dynamic' with probability p_dynamic, else a static batch, copy-paste
    augmented with probability p_copy_paste (the official copy_paste.prob)."""

    def __init__(self, pool: ScenePool, seed: int, p_dynamic: float = 0.5,
                 p_copy_paste: float = 0.5, views_range=(2, 4), input_targets: int = 0,
                 device=None):
        self.pool = pool
        self.device = device   # where the batch's tensors are made (the images converted to float)
        # input views also rendered as targets (each scene's first `input_targets` inputs, in
        # sequence order); 0 is the paper's recipe (targets are the other views only)
        self.input_targets = input_targets
        self.rng = np.random.default_rng([seed, 101])
        self.p_dynamic, self.p_copy_paste = p_dynamic, p_copy_paste
        self.views_range = views_range

    def batch(self, b: int) -> dict:
        rng, pool = self.rng, self.pool
        n, f = len(pool), pool.rgb.shape[1]
        r = rng.random()
        kind = "dynamic" if r < self.p_dynamic else (
            "copy-paste" if rng.random() < self.p_copy_paste else "static")
        k = int(rng.integers(self.views_range[0], self.views_range[1] + 1))
        scenes = rng.choice(n, size=b, replace=False)
        imgs, clean, paste = [], [], []
        for s in scenes:
            if kind == "dynamic":
                imgs.append(pool.rgb[s])
                clean.append(pool.rgb[s])
                paste.append(np.zeros(pool.mask[s].shape, bool))
            else:
                static = {"rgb": pool.static_rgb[s], "classes": pool.static_classes[s], "info": {}}
                if kind == "static":
                    imgs.append(static["rgb"])
                    paste.append(np.zeros(pool.mask[s].shape, bool))
                else:
                    src = int(rng.choice([i for i in range(n) if i != s]))
                    source = {"rgb": pool.rgb[src], "classes": pool.classes[src],
                              "mask": pool.mask[src], "seed": int(pool.seeds[src])}
                    cp = copy_paste(static, source, seed=int(rng.integers(1 << 30)))
                    imgs.append(cp["rgb"])
                    paste.append(cp["mask"])
                clean.append(static["rgb"])
        order = [np.sort(rng.permutation(f)[:k]) for _ in range(b)]
        inputs = torch.as_tensor(np.stack(order), dtype=torch.long)
        t_idx = [np.setdiff1d(np.arange(f), o) for o in order]
        if self.input_targets:
            t_idx = [np.sort(np.concatenate([t, o[:self.input_targets]])) for t, o in zip(t_idx, order)]
        targets = torch.as_tensor(np.stack(t_idx), dtype=torch.long)
        return {
            "kind": kind,
            "images": to_tensor(np.stack(imgs), self.device),   # [B, F, 3, H, W] what the model sees
            "clean": to_tensor(np.stack(clean), self.device),   # [B, F, 3, H, W] without pasted objects
            "paste": _on(torch.from_numpy(np.stack(paste)), self.device).float().unsqueeze(2),  # [B, F, 1, H, W]
            "inputs": _on(inputs, self.device), "targets": _on(targets, self.device),
            # the true cameras of every frame (the pasted objects do not move the camera)
            "c2w": _on(torch.from_numpy(pool.c2w[scenes]), self.device),            # [B, F, 4, 4]
            "fxfycxcy": _on(torch.from_numpy(pool.fxfycxcy[scenes]), self.device),  # [B, F, 4]
        }
