"""``spar-eval-compare``: two result JSONs side by side; do they agree?

  spar-eval-compare A.json B.json [--tolerance 0.005]

Every metric of every K is compared with an absolute tolerance (PSNR in dB, the others in
[0, 1]): the protocol asks engine and reference to agree to the second decimal. A metric that
is null on one side only, a K present on one side only, or different scene / frame /
target-view counts (not the same test set) also disagree. Exit code 0 when everything agrees,
1 when something differs, 2 for a bad command line or a file that is not a result.
"""

import argparse
import sys
from typing import Any, Dict, List, Optional, Sequence, Tuple

from .resultfile import ResultError, fmt, read_result, sorted_views
from .run_reference import METRIC_KEYS

PROG = "spar-eval-compare"


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        sys.stderr.write(f"{PROG}: error: {message} (see {self.prog} --help)\n")
        sys.exit(2)


def _tolerance(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = -1.0
    if not v >= 0.0:
        raise argparse.ArgumentTypeError(f"--tolerance must be a number >= 0, got {text!r}")
    return v


def compare(a: Dict[str, Any], b: Dict[str, Any], tol: float
            ) -> Tuple[List[List[str]], List[str]]:
    """(table rows, list of disagreements)."""
    rows: List[List[str]] = [["K", "metric", "A", "B", "|A-B|", ""]]
    bad: List[str] = []
    for key in ("scenes", "frames"):
        if a.get(key) != b.get(key):
            bad.append(f"{key}: {a.get(key)} vs {b.get(key)}")
    for k in sorted_views(set(a["results"]) | set(b["results"])):
        ra: Optional[Dict[str, Any]] = a["results"].get(k)
        rb: Optional[Dict[str, Any]] = b["results"].get(k)
        if ra is None or rb is None:
            bad.append(f"K={k}: only in {'B' if ra is None else 'A'}")
            continue
        if ra.get("target_views") != rb.get("target_views"):
            bad.append(f"K={k} target_views: {ra.get('target_views')} vs {rb.get('target_views')}")
        for m in METRIC_KEYS:
            va, vb = ra[m], rb[m]
            if va is None and vb is None:
                rows.append([k, m, "null", "null", "", "ok"])
                continue
            if va is None or vb is None:
                rows.append([k, m, fmt(m, va), fmt(m, vb), "", "NULL"])
                bad.append(f"K={k} {m}: null on one side")
                continue
            d = abs(float(va) - float(vb))
            ok = d <= tol
            rows.append([k, m, f"{va:.6f}", f"{vb:.6f}", f"{d:.6f}", "ok" if ok else "DIFF"])
            if not ok:
                bad.append(f"K={k} {m}: {va:.6f} vs {vb:.6f} (|diff| {d:.6f} > {tol})")
        for m in ("ms_per_scene",):   # informational: speed is expected to differ
            rows.append([k, m, fmt(m, ra.get(m)), fmt(m, rb.get(m)), "", ""])
    return rows, bad


def _describe(tag: str, path: str, d: Dict[str, Any]) -> str:
    return (f"{tag}: {path}  runner={d.get('runner')} precision={d.get('precision')} "
            f"mode={d.get('mode')} scenes={d.get('scenes')} frames={d.get('frames')} "
            f"model={d.get('model')}")


def main(argv: Optional[Sequence[str]] = None) -> int:
    p = _Parser(prog=PROG, description="Compare two spar-eval result JSONs metric by metric.")
    p.add_argument("a", metavar="A.json")
    p.add_argument("b", metavar="B.json")
    p.add_argument("--tolerance", type=_tolerance, default=0.005,
                   help="largest allowed absolute difference (default 0.005)")
    args = p.parse_args(argv)
    try:
        a, b = read_result(args.a), read_result(args.b)
    except ResultError as e:
        sys.stderr.write(f"{PROG}: error: {e}\n")
        return 2
    rows, bad = compare(a, b, args.tolerance)
    print(_describe("A", args.a, a))
    print(_describe("B", args.b, b))
    if a.get("mode") != b.get("mode"):
        print(f"note: different modes ({a.get('mode')} vs {b.get('mode')})")
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    for r in rows:
        print("  ".join(c.rjust(w) if i >= 2 else c.ljust(w)
                        for i, (c, w) in enumerate(zip(r, widths))).rstrip())
    if bad:
        print(f"DIFFERENT (tolerance {args.tolerance}): " + "; ".join(bad))
        return 1
    print(f"AGREE (tolerance {args.tolerance})")
    return 0
