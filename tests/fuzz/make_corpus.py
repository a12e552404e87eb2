#!/usr/bin/python3
"""Writes the fuzz seed corpora (committed; rerun after a format change):

    tests/fuzz/corpus/spar_reader/*.spar   small packed models (converter's safetensors writer,
                                            real tiny / full configs, every dtype, empty and
                                            scalar tensors, a non-finite weight, a model card,
                                            a SAM2.1 variant's metadata and tensors, quantized
                                            q8 / q4 matrices)
    tests/fuzz/corpus/checkpoint/*.pt      small torch.save checkpoints (bare state_dict, the
                                            training wrapper, parameters, views sharing a
                                            storage, a deflated zip, a TorchScript archive)

Files named regression_* are inputs that once found a bug, kept as found (the runs replay every
seed first). Seeds are small (a few KB) so that mutations hit the structure, not the payload. Values are
fixed (no randomness beyond torch.manual_seed), so rerunning changes nothing unless the
writers change.
"""

import argparse
import collections
import json
import sys
import zipfile
from pathlib import Path

import numpy as np
import torch

# Run by hand: the converter's root, found from here (nothing installed).
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "converter"))

from spar_convert import model_config  # noqa: E402
from spar_convert.convert import FORMAT, FORMAT_VERSION, QUANT_FORMAT_VERSION  # noqa: E402
from spar_convert.model_card import card_text  # noqa: E402
from spar_convert.safetensors_file import write_safetensors  # noqa: E402

OUT = Path(__file__).resolve().parent / "corpus"


def packed(path, config, tensors, components=None, card=None, extra=None):
    meta = {"format": FORMAT, "format_version": FORMAT_VERSION,
            "config": json.dumps(config, sort_keys=True, separators=(",", ":")), **(extra or {})}
    if components is not None:
        meta["components"] = json.dumps(components, sort_keys=True, separators=(",", ":"))
    if card is not None:
        meta["model_card"] = card_text(card)
    write_safetensors(path, tensors, meta)


def spar_seeds(out):
    out.mkdir(parents=True, exist_ok=True)
    tiny = model_config.tiny().to_dict()
    every_dtype = {
        "f32": np.arange(15, dtype=np.float32).reshape(3, 5) / 7,
        "f16": (np.arange(8, dtype=np.float16) - 4).reshape(4, 2),
        "i32": np.array([1, -2, 3], dtype=np.int32),
        "i64": np.array([[0, 2**40], [-1, 7]], dtype=np.int64),
        "u8": np.arange(7, dtype=np.uint8),
        "scalar": np.array(0.25, dtype=np.float32),
        "empty": np.zeros((0, 4), dtype=np.float32),
    }
    packed(out / "tiny_every_dtype.spar", tiny, every_dtype,
           {"spar": True, "dino": True, "lseg": True, "clip": False, "bpe": False})
    packed(out / "full_config.spar", model_config.full().to_dict(),
           {"pose_predictor.proj.weight": np.ones((2, 4), dtype=np.float32)})
    photometric = dict(tiny, use_lseg=False)
    packed(out / "photometric_no_components.spar", photometric,
           {"a": np.zeros(2, dtype=np.float16), "b": np.zeros(0, dtype=np.int64)})
    packed(out / "model_card.spar", photometric, {"a": np.zeros(2, dtype=np.float32)},
           card={"kind": "demonstration", "about": "made for the fuzzer",
                 "measured": {"what": "K=3", "psnr_db": 18.14, "baseline": "copying", "baseline_psnr_db": 20.02},
                 "training": {"data": "takes of 3 rooms", "steps": 870, "minutes": 29.0}})
    # A SAM2.1 variant's metadata (spar-convert --sam2) and a few of its tensors under sam2.
    sam2 = {"name": "fuzz", "embed_dim": 8, "num_heads": 1, "stages": [1, 1, 2, 1], "global_att_blocks": [3],
            "window_spec": [8, 4, 6, 3], "window_pos_embed_bkg_spatial_size": [7, 7], "d_model": 64,
            "backbone_channel_list": [64, 32, 16, 8]}
    packed(out / "sam2.spar", photometric,
           {"sam2.image_encoder.trunk.pos_embed": np.ones((1, 8, 7, 7), dtype=np.float32),
            "sam2.no_mem_embed": np.zeros((1, 1, 64), dtype=np.float16)},
           extra={"sam2_config": json.dumps(sam2, sort_keys=True, separators=(",", ":"))})
    # Quantized matrices (format version 2, FORMAT.md "Quantized matrices"): a q8 and a q4 one,
    # and a q8 convolution kernel [2, 8, 2, 2] (its matrix [2, 32]).
    packed(out / "quantized.spar", photometric,
           {"w": (np.arange(64) % 9 - 4).astype(np.int8).reshape(2, 32),
            "w.qscale": np.array([[0.5], [0.25]], dtype=np.float32),
            "v": np.full((1, 32), 0x1F, dtype=np.uint8),
            "v.qscale": np.array([[1.0, 2.0]], dtype=np.float32),
            "c": (np.arange(64) % 7 - 3).astype(np.int8).reshape(2, 32),
            "c.qscale": np.array([[0.125], [2.0]], dtype=np.float32)},
           extra={"format_version": QUANT_FORMAT_VERSION,
                  "quantized": json.dumps({"w": {"bits": 8, "block": 32, "shape": [2, 32]},
                                           "v": {"bits": 4, "block": 32, "shape": [1, 64]},
                                           "c": {"bits": 8, "block": 32, "shape": [2, 8, 2, 2]}},
                                          sort_keys=True, separators=(",", ":"))})
    packed(out / "nonfinite.spar", tiny,
           {"inf": np.array([1, np.inf], dtype=np.float32), "nan": np.array([np.nan], dtype=np.float16)})


def rezip(src, dst, compression):
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", compression) as zout:
        for info in zin.infolist():
            zout.writestr(info.filename, zin.read(info))


def checkpoint_seeds(out):
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(0)
    base = torch.arange(12, dtype=torch.float32).reshape(3, 4)
    bare = {
        "f32": base,
        "transposed": base.t(),        # a non-contiguous view of the same storage
        "row": base[1],                # a view with a storage offset
        "f16": torch.arange(4, dtype=torch.float16),
        "bf16": torch.ones(2, 2, dtype=torch.bfloat16),
        "i64": torch.tensor([1, -2, 2**40]),
        "bool": torch.tensor([[True, False], [False, True]]),
        "scalar": torch.tensor(3.5),
        "empty": torch.zeros(0, 4),
    }
    torch.save(bare, out / "bare.pt")
    rezip(out / "bare.pt", out / "deflated.pt", zipfile.ZIP_DEFLATED)
    linear = torch.nn.Linear(3, 2)
    wrapper = {
        "model": linear.state_dict(),  # an OrderedDict with _metadata, as training saves it
        "optimizer": {"state": {}, "param_groups": [{"lr": 0.1, "params": [0, 1]}]},
        "epoch": 3,
        "args": argparse.Namespace(lr=0.1),  # an unknown global: the reader skips this entry
    }
    torch.save(wrapper, out / "wrapper.pt")
    torch.save({"state_dict": collections.OrderedDict(p=torch.nn.Parameter(torch.ones(2, 2)))},
               out / "parameters.pt")
    torch.jit.save(torch.jit.script(torch.nn.Linear(2, 2)), str(out / "torchscript.pt"))


def main():
    spar_seeds(OUT / "spar_reader")
    checkpoint_seeds(OUT / "checkpoint")
    for f in sorted(OUT.rglob("*.*")):
        print("%6d  %s" % (f.stat().st_size, f.relative_to(OUT)))


if __name__ == "__main__":
    main()
