"""Reading result JSONs (PROTOCOL.md "Output JSON") for compare and table, and the number
formats the tools print."""

import json
import math
from typing import Any, Dict, Optional

from .run_reference import METRIC_KEYS


class ResultError(Exception):
    """A file that is not a spar-eval result (one-line message)."""


def read_result(path: str) -> Dict[str, Any]:
    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except OSError as e:
        raise ResultError(f"cannot read {path}: {e.strerror or e}")
    except ValueError as e:
        raise ResultError(f"{path} is not JSON: {e}")
    if not isinstance(doc, dict) or doc.get("format") != "spar-eval":
        raise ResultError(f"{path} is not a spar-eval result (format != \"spar-eval\")")
    if doc.get("version") != 1:
        raise ResultError(f"{path}: unsupported version {doc.get('version')!r}")
    res = doc.get("results")
    if not isinstance(res, dict) or not res:
        raise ResultError(f"{path}: no results")
    for k, r in res.items():
        if not isinstance(r, dict) or any(m not in r for m in METRIC_KEYS):
            raise ResultError(f"{path}: results[{k!r}] lacks a metric")
        for m in METRIC_KEYS:
            v = r[m]
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                                  or not math.isfinite(v)):
                raise ResultError(f"{path}: results[{k!r}].{m} is not a number or null")
    return doc


def sorted_views(keys) -> list:
    """K keys in numeric order ("2" < "10")."""
    return sorted(keys, key=lambda k: (int(k) if str(k).isdigit() else 1 << 30, str(k)))


def fmt(metric: str, v: Optional[float]) -> str:
    """PSNR in dB with 2 decimals, ratios with 4, times as integers; null as '-'."""
    if v is None:
        return "-"
    if metric.startswith("psnr"):
        return f"{v:.2f}"
    if metric in ("ms_per_scene", "seconds"):
        return f"{v:.0f}" if metric == "ms_per_scene" else f"{v:.1f}"
    return f"{v:.4f}"
