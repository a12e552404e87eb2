"""--sam2: which tensors of a SAM2.1 checkpoint the packed file gets, checked against the variant.

The variant is ``--sam2-config`` (a name or an official-layout YAML), else the one the file's
name says (``sam2.1_hiera_large.pt``), else the official variant whose tensor shapes the
checkpoint has. Every tensor of the refinement path (sam2_config.used_tensors) must be there
with its shape; the object-score head and hypernetwork 0 (computed by the official path,
never part of its result) and the video path's tensors are dropped; any other tensor means the
checkpoint is not the variant named, and is refused, naming it.
"""

from __future__ import annotations

from .sam2_config import (VARIANTS, Sam2Config, Sam2ConfigError, discarded_tensors, guess_variant,
                          is_unused, read_sam2_config, used_tensors, variant)

PACKED_PREFIX = "sam2."


class Sam2PlanError(ValueError):
    """One line, naming the tensor or the variant."""


def matching_variant(shapes):
    """The official variant whose refinement-path tensors the checkpoint has exactly, or None."""
    for name in VARIANTS:
        want = used_tensors(variant(name))
        if all(tuple(shapes.get(k, ())) == s for k, s in want.items()):
            return variant(name)
    return None


def resolve(src_shapes, path, config_spec):
    """The Sam2Config for a checkpoint at `path` whose tensors have `src_shapes` (key -> shape),
    and where it came from (for the conversion record)."""
    try:
        if config_spec:
            return read_sam2_config(config_spec), "--sam2-config %s" % config_spec
        named = guess_variant(path)
        if named is not None:
            return named, "the file name"
    except Sam2ConfigError as e:
        raise Sam2PlanError(str(e)) from None
    found = matching_variant(src_shapes)
    if found is None:
        raise Sam2PlanError("the SAM2 checkpoint %s matches none of the official variants (%s): give "
                            "--sam2-config NAME|YAML" % (path, ", ".join(VARIANTS)))
    return found, "its tensor shapes"


def plan(src, cfg: Sam2Config, keep, drop):
    """Adds the refinement path's tensors of `src` (a converter Source of component sam2) through
    keep(src, key, shape), drops the rest through drop(key, reason); refuses what the variant
    does not know."""
    used = used_tensors(cfg)
    discarded = discarded_tensors(cfg)
    for key, shape in used.items():
        keep(src, key, shape)
    for key in src.tensors:
        if key in used:
            continue
        if key in discarded:
            drop(key, "SAM2: computed by the official path, never part of its result")
        elif is_unused(key):
            drop(key, "SAM2: video path or point/box prompts, not on the refinement path")
        else:
            raise Sam2PlanError("tensor %r (%s) is not part of %s: a checkpoint of another variant? "
                                "(give --sam2-config NAME|YAML)" % (src.stored(key), src.origin[key].split(":")[0],
                                                                    cfg.name))
    return used
