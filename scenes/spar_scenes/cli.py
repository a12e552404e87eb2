"""``spar-scenes``: write procedural SPAR scenes as folders.

  spar-scenes generate --seed S [--frames 8] [--size 128 | --size WxH] [--static]
                       [--paste-from SEED] [--depth] --out DIR
  spar-scenes split --split train|test --count N [--start I] [--kind dynamic|static|copy-paste]
                    [--frames 8] [--size 128] [--depth] --out DIR

generate writes one scene folder (writer.py lists the files). --static: the same room and
cameras without distractors; --paste-from SEED: the static scene with the distractor
cut-outs of scene SEED pasted on (copy-paste augmentation, the pasted mask as ground truth).
split writes DIR/scene_<seed>/ for scenes start .. start+count-1 of the split's seed range
(splits.py) plus DIR/index.json; --kind copy-paste pastes scene seed+1's distractors (the
split's first seed after its last) onto scene seed's static version.
Errors: one line ``spar-scenes: error: ...`` on stderr; exit code 2 for a command line that
cannot mean anything, 1 for anything found wrong on the way (e.g. DIR exists).
"""

import argparse
import json
import os
import sys
import time
from typing import Optional, Sequence

PROG = "spar-scenes"
MAX_SIDE = 4096
MAX_FRAMES = 1000


class CliError(Exception):
    """A user-facing error: one line, exit code 1."""


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line on stderr (exit code 2)."""

    def error(self, message):
        sys.stderr.write(f"{PROG}: error: {message} (see {self.prog} --help)\n")
        sys.exit(2)


def _size(text: str):
    """'128' -> (128, 128); 'WxH' -> (H, W) (generate_scene takes height, width)."""
    try:
        if "x" in text.lower():
            w, h = (int(s) for s in text.lower().split("x"))
        else:
            w = h = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid size {text!r} (N or WxH)")
    if not (1 <= w <= MAX_SIDE and 1 <= h <= MAX_SIDE):
        raise argparse.ArgumentTypeError(f"size {text!r} out of range 1..{MAX_SIDE}")
    return (h, w)


def _bounded(lo: int, hi: Optional[int], what: str):
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid {what} {text!r}")
        if v < lo or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(
                f"{what} {v} out of range ({lo}..{hi if hi is not None else 'inf'})")
        return v
    return parse


def _check_out(path: str) -> None:
    if os.path.exists(path):
        raise CliError(f"output directory exists: {path}")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise CliError(f"parent directory does not exist: {parent}")


def _make(seed: int, kind: str, frames: int, size, paste_from: Optional[int] = None) -> dict:
    from .generate import copy_paste, generate_scene
    if kind == "dynamic":
        return generate_scene(seed, frames, size, distractors=True)
    static = generate_scene(seed, frames, size, distractors=False)
    if kind == "static":
        return static
    return copy_paste(static, generate_scene(paste_from, frames, size), seed=seed)


def cmd_generate(args) -> int:
    from .writer import write_scene
    _check_out(args.out)
    if args.static and args.paste_from is not None:
        raise CliError("--static and --paste-from exclude each other")
    kind = "copy-paste" if args.paste_from is not None else ("static" if args.static else "dynamic")
    t = time.perf_counter()
    scene = _make(args.seed, kind, args.frames, args.size, args.paste_from)
    write_scene(scene, args.out, depth=args.depth)
    sys.stderr.write(f"{PROG}: {kind} scene {args.seed} ({args.frames} frames, "
                     f"{args.size[1]}x{args.size[0]}) -> {args.out} in {time.perf_counter() - t:.2f} s\n")
    return 0


def cmd_split(args) -> int:
    from .splits import SPLITS, split_seeds
    from .writer import staged_dir, write_files
    _check_out(args.out)
    try:
        seeds = split_seeds(args.split, args.count, args.start)
    except ValueError as e:
        raise CliError(str(e))
    lo, hi = SPLITS[args.split]
    t = time.perf_counter()
    index = []
    with staged_dir(args.out) as d:
        for j, s in enumerate(seeds):
            src = s + 1 if s + 1 < hi else lo
            scene = _make(s, args.kind, args.frames, args.size, src)
            name = f"scene_{s:07d}"
            os.mkdir(os.path.join(d, name))
            write_files(scene, os.path.join(d, name), depth=args.depth)
            entry = {"seed": s, "kind": args.kind, "path": name,
                     "frames_with_distractors": [int(i) for i in scene["has_distractors"].nonzero()[0]]}
            if args.kind == "copy-paste":
                entry["source_seed"] = src
            index.append(entry)
            end = "\r" if sys.stderr.isatty() else "\n"
            sys.stderr.write(f"{PROG}: {j + 1}/{len(seeds)} scenes{end}")
        with open(os.path.join(d, "index.json"), "w", encoding="utf-8") as fh:
            json.dump({"split": args.split, "kind": args.kind, "frames": args.frames,
                       "width": args.size[1], "height": args.size[0], "scenes": index}, fh, indent=1)
            fh.write("\n")
    sys.stderr.write(f"{PROG}: {len(seeds)} {args.kind} scenes of split {args.split} -> "
                     f"{args.out} in {time.perf_counter() - t:.1f} s\n")
    return 0


def _common(p) -> None:
    p.add_argument("--frames", type=_bounded(1, MAX_FRAMES, "frame count"), default=8,
                   help="frames per scene (default 8)")
    p.add_argument("--size", type=_size, default=(128, 128), metavar="N|WxH",
                   help="image size: N for N x N or WIDTHxHEIGHT (default 128)")
    p.add_argument("--depth", action="store_true", help="also write depth.npy (float32 z-depth)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (must not exist)")


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(prog=PROG, description="Procedural indoor scenes with moving distractors "
                 "for training and evaluating SPAR.")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    p = sub.add_parser("generate", help="write one scene folder",
                       description="Write one scene: rgb/class/mask PNGs per frame, scene.json, "
                       "classes.json, transforms.json.")
    p.add_argument("--seed", required=True, type=_bounded(0, None, "seed"))
    p.add_argument("--static", action="store_true", help="no distractors (same room and cameras)")
    p.add_argument("--paste-from", type=_bounded(0, None, "seed"), metavar="SEED",
                   help="copy-paste: the static scene with scene SEED's distractor cut-outs")
    _common(p)
    p.set_defaults(func=cmd_generate)
    p = sub.add_parser("split", help="write many scenes of the train or test seed range",
                       description="Write scenes start .. start+count-1 of a split as "
                       "DIR/scene_<seed>/ plus DIR/index.json.")
    p.add_argument("--split", required=True, choices=("train", "test"))
    p.add_argument("--count", required=True, type=_bounded(1, None, "count"))
    p.add_argument("--start", type=_bounded(0, None, "start"), default=0)
    p.add_argument("--kind", choices=("dynamic", "static", "copy-paste"), default="dynamic")
    _common(p)
    p.set_defaults(func=cmd_split)
    return ap


def _one_line(e: BaseException) -> str:
    s = str(e).strip().replace("\n", " ")
    return s if s else e.__class__.__name__


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except CliError as e:
        sys.stderr.write(f"{PROG}: error: {_one_line(e)}\n")
        return 1
    except KeyboardInterrupt:
        sys.stderr.write(f"{PROG}: error: interrupted\n")
        return 1
    except Exception as e:  # unexpected: still one line, no traceback
        sys.stderr.write(f"{PROG}: error: {e.__class__.__name__}: {_one_line(e)}\n")
        return 1
