"""SPAR checkpoint converter: reads PyTorch checkpoints without torch, writes safetensors.

Modules:
  torch_checkpoint  -- restricted, lazy reader of torch.save zip checkpoints (no code execution)
  safetensors_file  -- streaming, atomic safetensors writer and a validating memory-mapped reader
  model_config      -- SparConfig and the backbone size presets (shared with spar_reference)
  convert           -- the spar-convert command (checkpoint -> packed file, see ../FORMAT.md)

Only the Python standard library and numpy are used here; torch is never imported.
The names below are re-exported lazily (so `python3 -m spar_convert.torch_checkpoint` runs cleanly).
"""

import importlib

_EXPORTS = {
    "CheckpointError": "torch_checkpoint",
    "TensorRef": "torch_checkpoint",
    "Checkpoint": "torch_checkpoint",
    "open_checkpoint": "torch_checkpoint",
    "load_state_dict": "torch_checkpoint",
    "SafetensorsError": "safetensors_file",
    "SafetensorsWriter": "safetensors_file",
    "SafetensorsFile": "safetensors_file",
    "TensorSpec": "safetensors_file",
    "TensorInfo": "safetensors_file",
    "write_safetensors": "safetensors_file",
    "read_safetensors": "safetensors_file",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError("module %r has no attribute %r" % (__name__, name))
    return getattr(importlib.import_module("." + module, __name__), name)


def __dir__():
    return sorted(list(globals()) + __all__)
