"""The model card of a packed model (`__metadata__.model_card`, converter/FORMAT.md): what the
model is, in the words a user reads before they judge the engine by its renders.

A card is a JSON object; the one kind today is a demonstration model (one trained on this
project's CPU, whose renders show a room's layout rather than its detail):

    {"kind": "demonstration",
     "about": "trained on this project's 2-core CPU for 58 minutes on procedural rooms, it
               renders a room's layout, not its detail",
     "measured": {"what": "held-out K=3", "psnr_db": 18.14,
                  "baseline": "copying the nearest input", "baseline_psnr_db": 20.02}}

`spar render` prints it as one line and its index.html opens with it (model/model_card.cpp
makes the sentence; both read the same fields). An optional `training` record says how it was
made, for whoever reads the file: `{"data": "<what it was trained or fitted on>", "steps": N,
"minutes": M}`.
"""

import json
import math

KINDS = ("demonstration",)
MEASURED = {"what": str, "psnr_db": float, "baseline": str, "baseline_psnr_db": float}
TRAINING = ("data", "steps", "minutes")


class ModelCardError(Exception):
    """A card that cannot be stored. One-line message naming the field."""


def check_card(card, where):
    """The card, checked: a JSON object with a known kind, `about` and, if given, `measured`
    with every field (numbers finite). `where` names the card in errors."""
    if not isinstance(card, dict):
        raise ModelCardError("%s: a model card is a JSON object" % where)
    unknown = sorted(set(card) - {"kind", "about", "measured", "training"})
    if unknown:
        raise ModelCardError("%s: unknown field %r (known: kind, about, measured, training)" % (where, unknown[0]))
    if card.get("kind") not in KINDS:
        raise ModelCardError("%s: kind must be one of %s, not %r" % (where, ", ".join(KINDS), card.get("kind")))
    about = card.get("about")
    if not isinstance(about, str) or not about.strip() or "\n" in about:
        raise ModelCardError("%s: about must be a non-empty one-line string" % where)
    if "measured" in card:
        m = card["measured"]
        if not isinstance(m, dict) or set(m) != set(MEASURED):
            raise ModelCardError("%s: measured must have exactly %s" % (where, ", ".join(MEASURED)))
        for key, kind in MEASURED.items():
            v = m[key]
            if kind is float:
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise ModelCardError("%s: measured.%s must be a finite number, not %r" % (where, key, v))
            elif not isinstance(v, str) or not v.strip() or "\n" in v:
                raise ModelCardError("%s: measured.%s must be a non-empty one-line string" % (where, key))
    if "training" in card:
        t = card["training"]
        if not isinstance(t, dict) or set(t) != set(TRAINING):
            raise ModelCardError("%s: training must have exactly %s" % (where, ", ".join(TRAINING)))
        if not isinstance(t["data"], str) or not t["data"].strip() or "\n" in t["data"]:
            raise ModelCardError("%s: training.data must be a non-empty one-line string" % where)
        if isinstance(t["steps"], bool) or not isinstance(t["steps"], int) or t["steps"] < 1:
            raise ModelCardError("%s: training.steps must be a positive integer, not %r" % (where, t["steps"]))
        m = t["minutes"]
        if isinstance(m, bool) or not isinstance(m, (int, float)) or not math.isfinite(m) or m <= 0:
            raise ModelCardError("%s: training.minutes must be a finite positive number, not %r" % (where, m))
    return card


def read_card(path):
    """The card in JSON file `path`, checked."""
    try:
        with open(path, encoding="utf-8") as f:
            card = json.load(f)
    except FileNotFoundError:
        raise ModelCardError("model card not found: %s" % path) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ModelCardError("cannot read model card %s: %s" % (path, str(e).splitlines()[0])) from None
    return check_card(card, path)


def card_text(card):
    """The card as stored in the metadata (compact JSON, keys sorted)."""
    return json.dumps(card, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
