"""``spar-eval-reference``: evaluate a checkpoint with the PyTorch reference (PROTOCOL.md).

  spar-eval-reference --checkpoint X.pt [--config cfg.json] [--clip CLIP.pt] [--bpe BPE]
                      --scenes DIR [--views 2,3,4] [--no-gating | --assume-static]
                      [--float64] [--max-scenes N] [--threads N] --out result.json

Writes the result JSON (runner "reference") and prints a table. Errors: one line
``spar-eval-reference: error: ...`` on stderr, exit code 2 for a command line that cannot
mean anything, 1 for anything found wrong on the way; no output file in either case (the
JSON is written to a temporary file and renamed at the end).
"""

import argparse
import json
import os
import sys
import tempfile
from typing import Any, Dict, List, Optional, Sequence

from .resultfile import fmt, sorted_views

PROG = "spar-eval-reference"


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line on stderr (exit code 2)."""

    def error(self, message):
        sys.stderr.write(f"{PROG}: error: {message} (see {self.prog} --help)\n")
        sys.exit(2)


def _views(text: str) -> List[int]:
    try:
        ks = [int(x) for x in text.replace(" ", "").split(",") if x != ""]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--views must be comma-separated integers, got {text!r}")
    if not ks or len(set(ks)) != len(ks) or any(k < 2 for k in ks):
        raise argparse.ArgumentTypeError(f"--views needs distinct K >= 2, got {text!r}")
    return ks


def _positive(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return n


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description="Evaluate a SPAR checkpoint on a test set of scene "
                "folders with the PyTorch reference (evaluation/PROTOCOL.md).")
    p.add_argument("--checkpoint", required=True, metavar="X.pt")
    p.add_argument("--config", metavar="tiny|full|PATH",
                   help="model config; default: inferred from the checkpoint as spar-reference does")
    p.add_argument("--clip", metavar="CLIP.pt",
                   help="CLIP text weights (state_dict or spar-train teacher file) when the "
                        "checkpoint carries none under lseg_model.clip_pretrained.*")
    p.add_argument("--bpe", metavar="PATH", help="CLIP BPE merges table (default as spar-reference)")
    p.add_argument("--scenes", required=True, metavar="DIR",
                   help="test set: DIR/<scene>/ folders as spar-scenes split writes them")
    p.add_argument("--views", type=_views, default=[2, 3, 4], metavar="2,3,4",
                   help="numbers of input views K (default 2,3,4)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--no-gating", action="store_true",
                      help="CV-DRP runs (masks scored) but no input token is gated")
    mode.add_argument("--assume-static", action="store_true",
                      help="no DINOv3 / CV-DRP, no gating; mask metrics null")
    p.add_argument("--float64", action="store_true", help="run the model in float64")
    p.add_argument("--max-scenes", type=_positive, metavar="N", help="only the first N scenes")
    p.add_argument("--threads", type=_positive, default=2, metavar="N",
                   help="torch threads (default 2)")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.add_argument("--out", required=True, metavar="result.json")
    return p


def table(doc: Dict[str, Any]) -> str:
    cols = [("K", None), ("targets", None), ("PSNR", "psnr"), ("SSIM", "ssim"),
            ("mask mIoU", "mask_miou"), ("IoU dyn", "mask_iou_dynamic"),
            ("recall", "mask_recall"), ("sem mIoU", "sem_miou"), ("accuracy", "sem_accuracy"),
            ("ms/scene", "ms_per_scene"), ("seconds", "seconds")]
    rows = [[c for c, _ in cols]]
    for k in sorted_views(doc["results"]):
        r = doc["results"][k]
        rows.append([k, str(r["target_views"])] + [fmt(m, r[m]) for _, m in cols[2:]])
    widths = [max(len(row[i]) for row in rows) for i in range(len(cols))]
    head = (f"{doc['runner']} {doc['precision']} mode={doc['mode']} scenes={doc['scenes']} "
            f"frames={doc['frames']} model={doc['model']}")
    lines = [head] + ["  ".join(c.rjust(w) for c, w in zip(row, widths)) for row in rows]
    return "\n".join(lines)


def write_json_atomic(path: str, doc: Dict[str, Any]) -> None:
    d = os.path.dirname(path)
    fd, tmp = tempfile.mkstemp(prefix=os.path.basename(path) + ".tmp-", dir=d)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(doc, f, indent=1)
            f.write("\n")
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        out = os.path.abspath(args.out)
        if not os.path.isdir(os.path.dirname(out)):
            raise ValueError(f"parent directory does not exist: {os.path.dirname(out)}")
        if os.path.isdir(out):
            raise ValueError(f"--out is a directory: {out}")
        import torch
        from .run_reference import Options, evaluate
        torch.set_num_threads(args.threads)
        mode = ("no-gating" if args.no_gating else
                "assume-static" if args.assume_static else "default")
        opts = Options(checkpoint=args.checkpoint, scenes=args.scenes, config=args.config,
                       clip=args.clip, bpe=args.bpe, views=args.views, mode=mode,
                       float64=args.float64, max_scenes=args.max_scenes)
        log = (lambda s: None) if args.quiet else (lambda s: sys.stderr.write(s + "\n"))
        doc = evaluate(opts, log)
        write_json_atomic(out, doc)
        print(table(doc))
        return 0
    except KeyboardInterrupt:
        sys.stderr.write(f"{PROG}: error: interrupted\n")
        return 1
    except Exception as e:  # EvalError and anything unexpected: one line, no traceback
        msg = str(e).strip().replace("\n", " ") or e.__class__.__name__
        if e.__class__.__name__ not in ("EvalError", "ValueError"):
            msg = f"{e.__class__.__name__}: {msg}"
        sys.stderr.write(f"{PROG}: error: {msg}\n")
        return 1
