"""spar_scenes: seeded procedural indoor scenes with moving distractors for SPAR.

    from spar_scenes import generate_scene, copy_paste, CLASS_NAMES
    s = generate_scene(seed=3, n_frames=8, size=128)          # dict of numpy arrays
    st = generate_scene(seed=3, n_frames=8, size=128, distractors=False)  # same room, no one in it
    cp = copy_paste(st, generate_scene(seed=4), seed=3)        # cut-outs of seed 4 pasted on st

See README.md in this folder for the world, the conventions and the files the CLI writes.
"""

from .classes import CLASS_NAMES, CLASS_ID, DYNAMIC_CLASSES, PALETTE  # noqa: F401
from .generate import generate_scene, copy_paste  # noqa: F401
from .splits import SPLITS, split_seeds  # noqa: F401
