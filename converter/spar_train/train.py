"""One training run of the small SPAR: scene pool -> semantic teacher -> SPAR with the paper's
losses -> official-layout checkpoint -> packed model (spar-convert). Deterministic for a seed
(torch and numpy generators seeded; the same thread count gives the same floats)."""
import json
import math
import os
import subprocess
import sys
import time
from collections import OrderedDict

import numpy as np
import torch

from spar_reference import dino_v3, lseg as lseg_mod
from spar_reference.cli import add_clip_text
from spar_reference.spar import SPAR, _cosine_with_warmup

from .config import small_config
from .data import ScenePool, Sampler
from .losses import spar_losses
from .teacher import text_encoder, train_lseg

CONVERTER = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _round_to_fp16(sd):
    """Every float tensor rounded to the nearest float16 value (kept as float32): the packed
    model then stores F16 weight matrices exactly, and the engine in fp32 and the PyTorch
    reference on this checkpoint compute with identical weights."""
    return OrderedDict((k, v.half().float() if v.is_floating_point() else v) for k, v in sd.items())


class Run:
    def __init__(self, args):
        self.a = args
        os.makedirs(args.out, exist_ok=True)
        self.log_file = open(os.path.join(args.out, "train_log.txt"), "a")

    def log(self, msg):
        line = f"[{time.strftime('%H:%M:%S')}] {msg}"
        print(line, flush=True)
        self.log_file.write(line + "\n")
        self.log_file.flush()

    def build(self, pool):
        a, cfg = self.a, small_config()
        self.cfg = cfg
        with open(os.path.join(a.out, "config.json"), "w") as f:
            json.dump(cfg.to_dict(), f, indent=1)
        teacher_path = a.teacher or os.path.join(a.out, "teacher.pt")
        if os.path.isfile(teacher_path):
            t = torch.load(teacher_path)
            text = __import__("spar_reference.clip_text", fromlist=["x"]).CLIPTextEncoder(cfg.clip)
            text.load_state_dict(t["clip"])
            lseg = lseg_mod.LSegEncoder(cfg.lseg)
            lseg.load_state_dict(t["lseg"])
            emb, text_seed = t["class_embeddings"], t["clip_seed"]
            self.log(f"teacher from {teacher_path} (clip seed {text_seed}, "
                     f"lseg pixel accuracy {t['lseg_accuracy']:.3f})")
        else:
            text, emb, text_seed = text_encoder(cfg, a.bpe, log=self.log)
            torch.manual_seed(a.seed + 12)
            lseg = lseg_mod.LSegEncoder(cfg.lseg, seed=a.seed + 12)
            acc = train_lseg(lseg, pool, emb, a.lseg_steps, a.lseg_batch, a.seed, log=self.log)
            self.log(f"lseg teacher: pixel accuracy {acc:.3f} on a held-back batch")
            torch.save({"clip": text.state_dict(), "lseg": lseg.state_dict(),
                        "class_embeddings": emb, "clip_seed": text_seed, "lseg_accuracy": acc},
                       teacher_path)
        self.text = text
        # DINOv3 architecture, seeded random weights, frozen (no pretrained DINOv3 of this
        # size exists): CV-DRP sees a fixed random patch feature beside the image tokens.
        dino = dino_v3.DinoV3(cfg.dino, seed=a.seed + 11)
        torch.manual_seed(a.seed)
        model = SPAR(cfg, dino=dino, lseg=lseg).float()
        return model

    def checkpoint(self, model, opt, sched, step, path):
        ck = {"model": _round_to_fp16(model.state_dict()), "optimizer": opt.state_dict(),
              "lr_scheduler": sched.state_dict(), "fwdbwd_pass_step": step,
              "param_update_step": step}
        add_clip_text(ck, self.cfg, 0, False, encoder=self.text)
        ck["model"] = _round_to_fp16(ck["model"])
        tmp = path + ".tmp"
        torch.save(ck, tmp)
        os.replace(tmp, path)

    def train(self):
        a = self.a
        torch.set_num_threads(a.threads)
        torch.manual_seed(a.seed)
        t_start = time.time()
        pool = ScenePool(a.scenes, 8, 128, os.path.join(a.out, "..", "scene-cache")
                         if a.cache is None else a.cache, log=self.log)
        model = self.build(pool)
        sampler = Sampler(pool, a.seed, input_targets=a.input_targets)
        named = [(k, p) for k, p in model.named_parameters() if p.requires_grad]
        groups = [{"params": [p for _, p in named if p.dim() != 1], "weight_decay": 0.05},
                  {"params": [p for _, p in named if p.dim() == 1], "weight_decay": 0.0}]
        opt = torch.optim.AdamW(groups, lr=a.lr, betas=(0.9, 0.95))
        sched = torch.optim.lr_scheduler.LambdaLR(
            opt, lambda s: _cosine_with_warmup(s, a.warmup, a.steps))
        model.train()
        model._dino_v3.eval()
        model.lseg_model.eval()
        self.log(f"training {sum(p.numel() for _, p in named) / 1e6:.2f} M parameters, "
                 f"{a.steps} steps of {a.batch} scenes, lr {a.lr}, "
                 f"dynamic-region-aware loss {'off' if a.no_dynamic_loss else 'on'}, "
                 f"camera loss weight {a.pose_loss}")
        t0 = time.time()
        acc = {}
        for step in range(a.steps):
            batch = sampler.batch(a.batch)
            b, t = batch["targets"].shape
            ar = torch.arange(b)[:, None]
            with torch.no_grad():
                clean_targets = batch["clean"][ar, batch["targets"]].flatten(0, 1)
                teacher = model.lseg_model(clean_targets)
            out = model(batch["images"], batch["inputs"], batch["targets"])
            losses = spar_losses(out, batch, teacher, dynamic_weighting=not a.no_dynamic_loss,
                                 pose_weight=a.pose_loss)
            opt.zero_grad(set_to_none=True)
            losses["loss"].backward()
            gnorm = torch.nn.utils.clip_grad_norm_([p for _, p in named], 1.0)
            if torch.isfinite(gnorm):
                opt.step()
            sched.step()
            for k, v in losses.items():
                acc.setdefault(k, []).append(float(v))
            if (step + 1) % a.log_every == 0 or step + 1 == a.steps:
                el = time.time() - t0
                eta = el / (step + 1) * (a.steps - step - 1)
                avg = {k: np.mean(v) for k, v in acc.items()}
                self.log(f"step {step + 1}/{a.steps} loss {avg['loss']:.4f} recon {avg['recon']:.4f} "
                         f"sem {avg['sem']:.4f} bce {avg['bce']:.4f} reg {avg['reg']:.4f} "
                         f"pose {avg['pose']:.4f} "
                         f"psnr {avg['psnr']:.2f} dB lr {sched.get_last_lr()[0]:.2e} "
                         f"{el / (step + 1):.2f} s/step, eta {eta / 60:.1f} min")
                acc = {}
            if a.save_every and (step + 1) % a.save_every == 0 and step + 1 < a.steps:
                self.checkpoint(model, opt, sched, step + 1, os.path.join(a.out, "checkpoint.pt"))
                if a.keep_checkpoints:  # for learning curves (scripts/learning-curve.sh)
                    self.checkpoint(model, opt, sched, step + 1,
                                    os.path.join(a.out, f"checkpoint_step{step + 1:06d}.pt"))
        model.eval()
        ck = os.path.join(a.out, "checkpoint.pt")
        self.checkpoint(model, opt, sched, a.steps, ck)
        self.log(f"checkpoint {ck} ({time.time() - t_start:.0f} s in all)")
        packed = os.path.join(a.out, "model.spar")
        cmd = [sys.executable, os.path.join(CONVERTER, "spar-convert"), "-q", ck, "--config",
               os.path.join(a.out, "config.json"), "--bpe", a.bpe, "--fp16", "-o", packed]
        subprocess.run(cmd, check=True)
        self.log(f"packed model {packed} ({os.path.getsize(packed) / 1e6:.1f} MB)")
        return 0
