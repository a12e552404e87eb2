"""spar-train: train the small SPAR on procedural rooms (see converter/spar_train/README.md)."""
import argparse
import os
import sys


def default_bpe() -> str:
    # the repository's copy of CLIP's merges table (text/data/clip/, MIT licence beside it)
    here = os.path.dirname(os.path.abspath(__file__))
    return os.path.normpath(os.path.join(here, "..", "..", "text", "data", "clip",
                                         "bpe_simple_vocab_16e6.txt.gz"))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="spar-train", description=__doc__)
    p.add_argument("--out", required=True, help="run directory (checkpoint.pt, model.spar, log)")
    p.add_argument("--steps", type=int, default=1500)
    p.add_argument("--batch", type=int, default=2, help="scenes per step (8 views each)")
    p.add_argument("--lr", type=float, default=5e-4)
    p.add_argument("--warmup", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--scenes", type=int, default=400, help="train scenes in the pool")
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
                        "scripts/learning-curve.sh)")
    p.add_argument("--pose-loss", type=float, default=0.0, metavar="W",
                   help="weight of a camera loss against the generator's true cameras (not in the "
                        "paper's self-supervised recipe; 0, the default, leaves it out)")
    p.add_argument("--input-targets", type=int, default=0, metavar="N",
                   help="also render each scene's first N input views as targets (reconstruction of "
                        "what the model saw; not in the paper's recipe, which renders only the "
                        "other views; 0, the default, leaves it out)")
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
    if a.profile:
        from .profile_step import profile
        return profile(a)
    from .train import Run
    return Run(a).train()
