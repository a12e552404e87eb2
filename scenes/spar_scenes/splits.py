"""Train / test splits by seed: disjoint seed ranges, so no test room is ever trained on.

A split's i-th scene has seed SPLITS[split][0] + i. The static version of a seed
(distractors=False) is the same room and cameras without distractors.
"""

SPLITS = {"train": (0, 1_000_000), "test": (1_000_000, 1_010_000)}


def split_seeds(split: str, count: int, start: int = 0):
    """Seeds of scenes start .. start+count-1 of ``split``."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r} (train, test)")
    lo, hi = SPLITS[split]
    if count < 0 or start < 0 or lo + start + count > hi:
        raise ValueError(f"split {split} has {hi - lo} scenes; asked for {start}..{start + count - 1}")
    return list(range(lo + start, lo + start + count))


def split_of(seed: int) -> str:
    for name, (lo, hi) in SPLITS.items():
        if lo <= seed < hi:
            return name
    return "other"
