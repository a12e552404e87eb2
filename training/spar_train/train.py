"""One training run of the small SPAR: scene pool -> semantic teacher -> SPAR with the paper's
losses -> official-layout checkpoint -> packed model (spar-convert). Deterministic for a seed
(torch and numpy generators seeded; the same thread count gives the same floats)."""
import json
import os
import subprocess
import sys
import time
from collections import OrderedDict

import torch

from spar_reference import dino_v3, lseg as lseg_mod
from spar_reference.cli import add_clip_text
from spar_reference.spar import SPAR, _cosine_with_warmup

from . import init_from
from .config import small_config
from .data import ScenePool, Sampler
from .heldout import HeldOut
from .losses import spar_losses
from .teacher import text_encoder, train_lseg
from .time_budget import TimeBudget

# the converter tool, in the repository's converter/ beside this package's folder
SPAR_CONVERT = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
                            "converter", "spar-convert")


def _round_to_fp16(sd):
    """Every float tensor rounded to the nearest float16 value (kept as float32): the packed
    model then stores F16 weight matrices exactly, and the engine in fp32 and the PyTorch
    reference on this checkpoint compute with identical weights. On the CPU: a checkpoint
    written on a GPU loads anywhere (spar-convert reads CPU storages only)."""
    return OrderedDict((k, (v.half().float() if v.is_floating_point() else v).detach().cpu())
                       for k, v in sd.items())


def _to_cpu(obj):
    """Tensors of a nested state (the optimizer's) moved to the CPU."""
    if torch.is_tensor(obj):
        return obj.detach().cpu()
    if isinstance(obj, dict):
        return type(obj)((k, _to_cpu(v)) for k, v in obj.items())
    if isinstance(obj, (list, tuple)):
        return type(obj)(_to_cpu(v) for v in obj)
    return obj


def pick_device(name: str):
    """torch.device for --device (checked by the command line: cpu or an available cuda[:N])."""
    dev = torch.device(name)
    if dev.type == "cuda":
        # TF32 matrix products: training tolerates them, and the checkpoint is rounded to
        # fp16 anyway
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
    return dev


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
        a, cfg = self.a, small_config(self.a.image_size, self.a.scene_tokens)
        self.cfg = cfg
        with open(os.path.join(a.out, "config.json"), "w") as f:
            json.dump(cfg.to_dict(), f, indent=1)
        teacher_path = a.teacher or os.path.join(a.out, "teacher.pt")
        if getattr(a, "init_from", None):
            # the packed model's own teacher: its LSeg comes with the model's weights below,
            # its CLIP text tower from the file (a teacher trained here would not be the one
            # its semantic head learned from)
            from spar_reference.clip_text import CLIPTextEncoder
            text = CLIPTextEncoder(cfg.clip).float()
            text.load_state_dict(init_from.text_encoder_state(a.init_from))
            text.eval()
            lseg = lseg_mod.LSegEncoder(cfg.lseg)
            self.log(f"teacher from {a.init_from} (its LSeg and CLIP text tower)")
        elif os.path.isfile(teacher_path):
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
            acc = train_lseg(lseg.to(self.dev), pool, emb, a.lseg_steps, a.lseg_batch, a.seed,
                             log=self.log, device=self.dev)
            lseg.cpu()
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
        if getattr(a, "init_from", None):
            init_from.load_into(model, a.init_from, log=self.log)
        return model

    def train_modes(self, model):
        """Training mode but for the frozen parts: DINOv3 and the LSeg teacher, and every
        BatchNorm when the run starts from a packed model (init_from: they are identities there)."""
        model.train()
        model._dino_v3.eval()
        model.lseg_model.eval()
        if getattr(self.a, "init_from", None):
            init_from.freeze_batch_norms(model)

    def checkpoint(self, model, opt, sched, step, path):
        ck = {"model": _round_to_fp16(model.state_dict()), "optimizer": _to_cpu(opt.state_dict()),
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
        self.dev = pick_device(a.device)
        t_start = time.time()
        pool = ScenePool(a.scenes, 8, a.image_size, os.path.join(a.out, "..", "scene-cache")
                         if a.cache is None else a.cache, workers=a.workers, log=self.log,
                         fit_seeds=getattr(a, "fit_seeds", None))
        model = self.build(pool).to(self.dev)
        heldout = None
        if a.eval_scenes:
            heldout = HeldOut(a.eval_scenes, a.eval_views, self.cfg, self.text, a.bpe,
                              restore=self.train_modes)
        sampler = Sampler(pool, a.seed, input_targets=a.input_targets, device=self.dev)
        named = [(k, p) for k, p in model.named_parameters() if p.requires_grad]
        groups = [{"params": [p for _, p in named if p.dim() != 1], "weight_decay": 0.05},
                  {"params": [p for _, p in named if p.dim() == 1], "weight_decay": 0.0}]
        opt = torch.optim.AdamW(groups, lr=a.lr, betas=(0.9, 0.95))
        # the schedule's length: --steps, or fewer where --minutes sets a time budget (fixed
        # by `budget` once the step rate is measured)
        total = [a.steps]
        sched = torch.optim.lr_scheduler.LambdaLR(
            opt, lambda s: _cosine_with_warmup(s, a.warmup, total[0]))
        self.train_modes(model)
        self.log(f"training {sum(p.numel() for _, p in named) / 1e6:.2f} M parameters on "
                 f"{self.dev}, {a.steps} steps of {a.batch} scenes"
                 f"{f' (at most {a.minutes} min)' if a.minutes else ''}, lr {a.lr}, "
                 f"dynamic-region-aware loss {'off' if a.no_dynamic_loss else 'on'}, "
                 f"camera loss weight {a.pose_loss}")
        t0 = time.time()
        budget = TimeBudget(a.minutes, a.steps, a.eval_every, log=self.log)
        evals = []   # (step, seconds) of each held-out measurement (not training time)
        curve = os.path.join(a.out, "curve.jsonl")
        if os.path.exists(curve):
            os.remove(curve)   # this run's curve only (the log, by contrast, accumulates)

        def eval_seconds():
            return sum(sec for _, sec in evals)

        def evaluate(step):
            te = time.time()
            m = heldout.measure(model)
            evals.append((step, time.time() - te))
            minutes = (time.time() - t0 - eval_seconds()) / 60.0
            with open(curve, "a") as f:
                f.write(json.dumps({"step": step, "minutes": minutes, "views": a.eval_views, **m})
                        + "\n")
            fmt = lambda v, d=3: "n/a" if v is None else f"{v:.{d}f}"  # noqa: E731
            self.log(f"held-out step {step} ({minutes:.1f} min): PSNR {fmt(m['psnr'], 2)} dB "
                     f"(copy {fmt(m['psnr_nearest_input'], 2)}, mean colour "
                     f"{fmt(m['psnr_mean_colour'], 2)}) SSIM {fmt(m['ssim'])} semantic mIoU "
                     f"{fmt(m['sem_miou'])} mask mIoU {fmt(m['mask_miou'])} "
                     f"(K={a.eval_views}, {len(heldout.scenes)} scenes)")

        if heldout is not None:
            evaluate(0)
        acc = {}
        step = 0
        while step < total[0]:
            total[0] = budget.steps(step, total[0], eval_seconds(), len(evals))
            batch = sampler.batch(a.batch)
            b, t = batch["targets"].shape
            ar = torch.arange(b, device=self.dev)[:, None]
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
            step += 1
            for k, v in losses.items():
                acc.setdefault(k, []).append(v.detach())
            if step % a.log_every == 0 or step == total[0]:
                el = time.time() - t0 - eval_seconds()
                eta = el / step * (total[0] - step)
                avg = {k: float(torch.stack(v).float().mean()) for k, v in acc.items()}
                self.log(f"step {step}/{total[0]} loss {avg['loss']:.4f} recon {avg['recon']:.4f} "
                         f"sem {avg['sem']:.4f} bce {avg['bce']:.4f} reg {avg['reg']:.4f} "
                         f"pose {avg['pose']:.4f} "
                         f"psnr {avg['psnr']:.2f} dB lr {sched.get_last_lr()[0]:.2e} "
                         f"{el / step:.2f} s/step, eta {eta / 60:.1f} min")
                acc = {}
            if heldout is not None and (step % a.eval_every == 0 or step == total[0]):
                evaluate(step)
            if a.save_every and step % a.save_every == 0 and step < total[0]:
                self.checkpoint(model, opt, sched, step, os.path.join(a.out, "checkpoint.pt"))
                if a.keep_checkpoints:  # for learning curves (training/learning-curve.sh)
                    self.checkpoint(model, opt, sched, step,
                                    os.path.join(a.out, f"checkpoint_step{step:06d}.pt"))
            if budget.overrun() and step < total[0]:
                self.log(f"time budget overrun: stopping at step {step} of {total[0]} "
                         f"(the schedule cut short)")
                break
        if heldout is not None and evals[-1][0] != step:   # a run cut short by --minutes
            evaluate(step)
        model.eval()
        ck = os.path.join(a.out, "checkpoint.pt")
        self.checkpoint(model, opt, sched, step, ck)
        self.log(f"checkpoint {ck} after {step} steps ({time.time() - t_start:.0f} s in all)")
        if a.no_pack:
            return 0
        packed = os.path.join(a.out, "model.spar")
        cmd = [sys.executable, SPAR_CONVERT, "-q", ck, "--config",
               os.path.join(a.out, "config.json"), "--bpe", a.bpe, "--fp16", "-o", packed]
        subprocess.run(cmd, check=True)
        self.log(f"packed model {packed} ({os.path.getsize(packed) / 1e6:.1f} MB)")
        return 0
