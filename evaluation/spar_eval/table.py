"""``spar-eval-table``: a Markdown table of several result JSONs (for the README).

  spar-eval-table --row "SPAR (trained)=res.json" --row "no gating=res_ng.json"
                  [--views 2,3,4] [--out table.md]

One row per file (its label, then mode and precision), and per K the columns PSNR, copy PSNR
and mean PSNR (the baselines: nearest input copied, the inputs' mean colour), SSIM, mask mIoU,
recall, sem mIoU, accuracy, ms/scene. Null metrics print as '-'. Without --out
the table goes to stdout. Exit code 2 for a bad command line or a file that is not a result.
"""

import argparse
import os
import sys
from typing import Any, Dict, List, Optional, Sequence, Tuple

from .resultfile import ResultError, fmt, read_result, sorted_views

PROG = "spar-eval-table"
# "copy PSNR" / "mean PSNR": the baselines on the same pixels (PROTOCOL.md), so the margin shows
COLUMNS = [("PSNR", "psnr"), ("copy PSNR", "psnr_nearest_input"), ("mean PSNR", "psnr_mean_colour"),
           ("SSIM", "ssim"), ("mask mIoU", "mask_miou"),
           ("recall", "mask_recall"), ("sem mIoU", "sem_miou"), ("accuracy", "sem_accuracy"),
           ("ms/scene", "ms_per_scene")]


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        sys.stderr.write(f"{PROG}: error: {message} (see {self.prog} --help)\n")
        sys.exit(2)


def _row(text: str) -> Tuple[str, str]:
    # the label may itself contain '=': the path is after the LAST one
    label, sep, path = text.rpartition("=")
    if not sep or not label.strip() or not path:
        raise argparse.ArgumentTypeError(f'--row needs "LABEL=result.json", got {text!r}')
    return label.strip(), path


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def markdown(rows: List[Tuple[str, Dict[str, Any]]], views: List[str]) -> str:
    head = ["model", "mode"] + [f"K={k} {c}" for k in views for c, _ in COLUMNS]
    lines = ["| " + " | ".join(head) + " |",
             "|" + "|".join([":--", ":--"] + ["--:"] * (len(head) - 2)) + "|"]
    for label, doc in rows:
        cells = [_cell(label), f"{doc.get('mode')} ({doc.get('runner')}, {doc.get('precision')})"]
        for k in views:
            r = doc["results"].get(k)
            cells += [fmt(m, None if r is None else r.get(m)) for _, m in COLUMNS]
        lines.append("| " + " | ".join(cells) + " |")
    scenes = sorted({str(d.get("scenes")) for _, d in rows})
    lines.append("")
    lines.append(f"Scenes: {', '.join(scenes)}; PSNR (dB) and SSIM on static pixels of the "
                 "target views (copy: the nearest input frame as the rendering, mean: the "
                 "inputs' mean colour, same pixels); mask metrics over all frames ('-': not available); semantic "
                 "metrics on half-resolution label maps.")
    return "\n".join(lines) + "\n"


def main(argv: Optional[Sequence[str]] = None) -> int:
    p = _Parser(prog=PROG, description="Markdown table of spar-eval result JSONs.")
    p.add_argument("--row", type=_row, action="append", required=True, metavar="LABEL=FILE",
                   help="one table row: a label and a result JSON (repeat)")
    p.add_argument("--views", metavar="2,3,4",
                   help="the K columns (default: every K found in the files)")
    p.add_argument("--out", metavar="table.md", help="write here instead of stdout")
    args = p.parse_args(argv)
    try:
        rows = [(label, read_result(path)) for label, path in args.row]
    except ResultError as e:
        sys.stderr.write(f"{PROG}: error: {e}\n")
        return 2
    if args.views:
        views = [v for v in args.views.replace(" ", "").split(",") if v]
    else:
        views = sorted_views({k for _, d in rows for k in d["results"]})
    text = markdown(rows, views)
    if args.out:
        out = os.path.abspath(args.out)
        if not os.path.isdir(os.path.dirname(out)):
            sys.stderr.write(f"{PROG}: error: parent directory does not exist: "
                             f"{os.path.dirname(out)}\n")
            return 2
        with open(out, "w", encoding="utf-8") as f:
            f.write(text)
    else:
        sys.stdout.write(text)
    return 0
