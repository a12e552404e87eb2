"""spar-train: train the small SPAR on procedural rooms (see training/README.md)."""
import argparse
import os
import re
import sys


def default_bpe() -> str:
    # the repository's copy of CLIP's merges table (text/data/clip/, MIT licence beside it)
    here = os.path.dirname(os.path.abspath(__file__))
    return os.path.normpath(os.path.join(here, "..", "..", "text", "data", "clip",
                                         "bpe_simple_vocab_16e6.txt.gz"))


def check_device(name: str):
    """None when training can run on `name`, else why not."""
    m = re.fullmatch(r"cpu|cuda(?::(\d+))?", name)
    if not m:
        return "cpu or cuda[:N]"
    if name.startswith("cuda"):
        import torch
        if not torch.cuda.is_available():
            return "this PyTorch sees no CUDA device"
        if m.group(1) is not None and int(m.group(1)) >= torch.cuda.device_count():
            return f"this PyTorch sees {torch.cuda.device_count()} CUDA device(s)"
    return None


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="spar-train", description=__doc__)
    p.add_argument("--out", required=True, help="run directory (checkpoint.pt, model.spar, log)")
    p.add_argument("--steps", type=int, default=1500)
    p.add_argument("--batch", type=int, default=2, help="scenes per step (8 views each)")
    p.add_argument("--lr", type=float, default=5e-4)
    p.add_argument("--warmup", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--image-size", type=int, default=128, metavar="N",
                   help="square image size of the scenes and the model, a multiple of 16 (128)")
    p.add_argument("--scene-tokens", type=int, default=64, metavar="N",
                   help="the scene encoder's latent tokens (64: one view's patches at 128x128; the "
                        "official model keeps three views' worth, 768 at 256x256)")
    p.add_argument("--scenes", type=int, default=400, help="train scenes in the pool")
    p.add_argument("--fit-scenes", metavar="DIR",
                   help="fit the model to the rooms of this spar-scenes folder (its index.json's "
                        "seeds) instead of training on many rooms: the pool is --scenes takes of "
                        "those rooms (other camera arcs, other moments of their movers), never "
                        "their own frames")
    p.add_argument("--init-from", metavar="MODEL.spar",
                   help="start from the weights of this packed model (same configuration) and its "
                        "teacher instead of a fresh initialization and a teacher trained here; its "
                        "BatchNorms stay frozen (spar_train/init_from.py)")
    p.add_argument("--cache", help="scene pool cache directory (default: OUT/../scene-cache)")
    p.add_argument("--lseg-steps", type=int, default=300)
    p.add_argument("--lseg-batch", type=int, default=8)
    p.add_argument("--teacher", help="reuse the teacher.pt of another run (same seed)")
    p.add_argument("--no-dynamic-loss", action="store_true",
                   help="ablation: plain MSE / cosine, no static-probability weighting")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--bpe", default=default_bpe(), help="CLIP BPE merges table")
    p.add_argument("--log-every", type=int, default=10)
    p.add_argument("--save-every", type=int, default=250)
    p.add_argument("--keep-checkpoints", action="store_true",
                   help="also keep each --save-every checkpoint as checkpoint_stepNNNNNN.pt (learning curves: "
                        "training/learning-curve.sh)")
    p.add_argument("--pose-loss", type=float, default=0.0, metavar="W",
                   help="weight of a camera loss against the generator's true cameras (not in the "
                        "paper's self-supervised recipe; 0, the default, leaves it out)")
    p.add_argument("--input-targets", type=int, default=0, metavar="N",
                   help="also render each scene's first N input views as targets (reconstruction of "
                        "what the model saw; not in the paper's recipe, which renders only the "
                        "other views; 0, the default, leaves it out)")
    p.add_argument("--device", default="cpu", help="cpu (default) or cuda[:N]: where the teacher and "
                   "SPAR train (the scene pool is always drawn on the CPU)")
    p.add_argument("--minutes", type=float, default=0.0, metavar="M",
                   help="time budget of the SPAR training loop: the schedule is fitted to the "
                        "steps that fit in M minutes (measured after the first steps), at most "
                        "--steps; 0 (default): exactly --steps")
    p.add_argument("--workers", type=int, default=2, help="processes rendering the scene pool")
    p.add_argument("--eval-scenes", metavar="DIR",
                   help="held-out scenes (spar-scenes split) measured during training: "
                        "OUT/curve.jsonl and the log get PSNR, SSIM, the copy and mean-colour "
                        "baselines, semantic and mask mIoU against steps and minutes")
    p.add_argument("--eval-every", type=int, default=250, metavar="N",
                   help="steps between held-out measurements (with --eval-scenes)")
    p.add_argument("--eval-views", type=int, default=3, metavar="K",
                   help="input views of the held-out measurement (3)")
    p.add_argument("--no-pack", action="store_true",
                   help="leave out packing model.spar (pack elsewhere with spar-convert)")
    p.add_argument("--profile", type=int, default=0, metavar="N",
                   help="instead of training: time N steps of the recipe by part (profile.json)")
    a = p.parse_args(argv)
    if not os.path.isfile(a.bpe):
        print(f"spar-train: error: CLIP merges table not found: {a.bpe} (give --bpe PATH)",
              file=sys.stderr)
        return 2
    if a.steps < 1 or a.batch < 1 or a.scenes < a.batch + 1:
        print("spar-train: error: --steps, --batch must be >= 1 and --scenes > --batch",
              file=sys.stderr)
        return 2
    if a.minutes < 0 or a.workers < 1 or a.eval_every < 1:
        print("spar-train: error: --minutes must be >= 0, --workers and --eval-every >= 1",
              file=sys.stderr)
        return 2
    if a.fit_scenes:
        from .fit import fit_seeds
        try:
            a.fit_seeds = fit_seeds(a.fit_scenes)
        except ValueError as e:
            print(f"spar-train: error: --fit-scenes {a.fit_scenes}: {e}", file=sys.stderr)
            return 2
    else:
        a.fit_seeds = None
    if a.init_from and not os.path.isfile(a.init_from):
        print(f"spar-train: error: --init-from {a.init_from}: no such file", file=sys.stderr)
        return 2
    if a.eval_scenes and not os.path.isdir(a.eval_scenes):
        print(f"spar-train: error: --eval-scenes {a.eval_scenes}: not a directory", file=sys.stderr)
        return 2
    device_error = check_device(a.device)
    if device_error:
        print(f"spar-train: error: --device {a.device}: {device_error}", file=sys.stderr)
        return 2
    if a.image_size < 32 or a.image_size % 16:
        print(f"spar-train: error: --image-size {a.image_size} must be a multiple of 16, at least 32",
              file=sys.stderr)
        return 2
    if not 1 <= a.scene_tokens <= 1024:
        print(f"spar-train: error: --scene-tokens {a.scene_tokens} must be between 1 and 1024",
              file=sys.stderr)
        return 2
    if a.profile:
        from .profile_step import profile
        return profile(a)
    from .init_from import InitFromError
    from .train import Run
    try:
        return Run(a).train()
    except InitFromError as e:   # a packed model of another configuration: one line
        print(f"spar-train: error: {e}", file=sys.stderr)
        return 2
