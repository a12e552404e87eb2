"""Held-out metrics of the model being trained, measured inside the run (spar-train
--eval-scenes DIR --eval-every N): the learning curve (PSNR, SSIM, the nearest-input-copy and
mean-colour baselines on the same pixels, semantic and motion-mask mIoU against steps and
minutes) without packing a checkpoint, on whatever device trains. The numbers are those of
`spar-eval-reference` (the same predict and accumulation code, PROTOCOL.md) at one K."""
import time

import torch

from spar_eval.protocol import view_indices
from spar_eval.run_reference import (Accumulator, EvalError, LoadedModel, check_views,
                                     load_scenes, predict, Options)

KEYS = ("psnr", "ssim", "psnr_nearest_input", "psnr_mean_colour", "sem_miou", "mask_miou")


class HeldOut:
    def __init__(self, scenes_dir: str, views: int, cfg, text_encoder, bpe: str, restore=None):
        """restore(model): the run's training modes, set again after each measurement (default:
        train mode, DINOv3 and LSeg in eval mode)."""
        self.scenes = load_scenes(Options(checkpoint="", scenes=scenes_dir))
        frames = self.scenes[0].frames
        check_views([views], frames)
        want = (cfg.image_height, cfg.image_width)
        for s in self.scenes:
            if s.size != want:
                raise EvalError(f"{s.name}: {s.size[1]}x{s.size[0]} images, the model trains on "
                                f"{want[1]}x{want[0]}")
        self.inputs, self.targets = view_indices(frames, views)
        self.cfg, self.text, self.bpe = cfg, text_encoder, bpe
        self.classes = len(self.scenes[0].class_names)
        self.restore = restore

    def measure(self, model) -> dict:
        """Metrics of `model` (left in the train/eval mode it was in)."""
        was_training = model.training
        model.eval()
        lm = LoadedModel(model, self.cfg, self.text, self.bpe, torch.float32)
        acc = Accumulator(self.classes)
        t0 = time.perf_counter()
        try:
            for s in self.scenes:
                acc.add(s, self.inputs, self.targets,
                        predict(lm, s, self.inputs, self.targets, "default"))
        finally:
            if was_training and self.restore is not None:
                self.restore(model)
            else:
                model.train(was_training)
                # the frozen parts stay in eval mode (BatchNorm statistics, dropout)
                model._dino_v3.eval()
                model.lseg_model.eval()
        r = acc.result(time.perf_counter() - t0)
        return {k: r[k] for k in KEYS + ("seconds",)}
