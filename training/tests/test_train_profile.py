#!/usr/bin/python3
"""``spar-train --profile N``: a training step's time by part, on the real recipe (a few scenes
and steps, and 32x32 images, the smallest size the recipe takes, keep it to seconds). The parts must add up to the step, and the forward's modules
(with what lies outside them) to the forward.
Run: cd /work/main && /usr/bin/python3 -m pytest -q training/tests/test_train_profile.py
"""

import json
import os
import subprocess
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
TOOL = os.path.join(HERE, "..", "spar-train")


def test_profile_parts_add_up(tmp_path):
    out = tmp_path / "run"
    p = subprocess.run([sys.executable, TOOL, "--out", str(out), "--scenes", "3", "--batch", "2",
                        "--profile", "1", "--threads", "1", "--image-size", "32"], capture_output=True, text=True,
                       timeout=600)
    assert p.returncode == 0, p.stderr
    assert "s a step" in p.stdout
    doc = json.loads((out / "profile.json").read_text())
    assert doc["steps"] == 1 and doc["batch"] == 2
    parts = doc["parts"]
    for name in ("draw batch", "LSeg teacher (frozen)", "SPAR forward", "losses", "backward",
                 "clip + AdamW"):
        assert parts[name] > 0, name
    assert sum(parts.values()) == pytest.approx(doc["seconds_per_step"], rel=1e-9)
    modules = doc["forward_modules"]
    for name in ("transformer_encoder", "transformer_decoder", "cv_drp", "_dino_v3"):
        assert modules[name] > 0, name     # the stacks are timed through their blocks
    assert doc["forward_outside_modules"] >= 0
    assert sum(modules.values()) + doc["forward_outside_modules"] == \
        pytest.approx(parts["SPAR forward"], rel=1e-9)
    assert not (out / "checkpoint.pt").exists()   # profiling trains nothing to keep
