"""Which scenes a model fitted to a folder of rooms trains on (spar-train --fit-scenes): takes
1, 2, ... of the folder's rooms (spar_scenes.generate_scene's ``take``: other camera arcs and
other moments of the same rooms and movers), never take 0, the folder's own frames. No torch
here: the model card's maker (fitted_card.py) reads it too."""
import json
import os


def fit_seeds(scenes_dir):
    """The room seeds of a spar-scenes folder (its index.json); ValueError when it has none."""
    path = os.path.join(scenes_dir, "index.json")
    try:
        with open(path) as f:
            index = json.load(f)
        seeds = [int(s["seed"]) for s in index["scenes"]]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ValueError(f"not a spar-scenes folder ({path}: {e})") from None
    if not seeds:
        raise ValueError(f"{path} lists no scenes")
    return seeds


def fit_jobs(seeds, count):
    """The (seed, take) pairs of a pool fitted to the rooms ``seeds``: takes 1, 2, ... of each
    room in turn (never take 0, the room's own shoot), ``count`` in all."""
    seeds = [int(s) for s in seeds]
    return [(seeds[i % len(seeds)], 1 + i // len(seeds)) for i in range(count)]
