#!/usr/bin/python3
"""Model configuration of the SPAR reference: every size the model needs.

The definitions live in ``spar_convert.model_config`` (standard library only), so that the
converter, which must run without PyTorch, reads and writes the same configuration; this
module re-exports them under their usual names (``SparConfig``, presets ``full()`` and
``tiny()``, ``PRESETS``, ``get_config``). See that module for the fields and file formats.
"""

from spar_convert.model_config import (  # noqa: F401
    PRESETS, SparConfig, full, get_config, tiny)

__all__ = ["PRESETS", "SparConfig", "full", "get_config", "tiny"]
