#!/usr/bin/python3
"""spar-convert --sam2 (spar_convert.sam2_config, sam2_plan): the four official SAM2.1 variants
have exactly the official tensors (reference/data/sam2/keys_hiera_{l,t}.tsv, the key lists of the
official model definition, read by spar_reference.sam2.official_keys); a checkpoint in the official layout converts with only the
refinement path's tensors packed, byte for byte; a variant described by an official-layout YAML
converts; a wrong shape, a missing tensor, a tensor of another variant, a NaN, an unknown name
or an unsupported YAML field is refused in one line, with no file written.

Cheap by design: hiera_t and a tiny YAML variant are written and converted; hiera_s, b+ and l
are checked through the plan on their shapes (the same code, without 1.5 GB of files)."""
import io
import json
import math
from contextlib import redirect_stderr, redirect_stdout
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from spar_convert.convert import is_matrix, main
from spar_convert.safetensors_file import SafetensorsFile
from spar_convert.sam2_config import (VARIANTS, Sam2Config, Sam2ConfigError, discarded_tensors, is_unused,
                                      read_sam2_config, used_tensors, variant)
from spar_convert import sam2_plan
from spar_reference import make_checkpoint as make_spar_checkpoint, tiny
from spar_reference.sam2 import make_checkpoint, official_keys, video_path_shapes

torch.set_num_threads(1)

TINY_YAML = """\
model:
  image_encoder:
    scalp: 1
    trunk:
      _target_: sam2.modeling.backbones.hieradet.Hiera
      embed_dim: 8
      num_heads: 1
      stages: [1, 1, 2, 2]
      global_att_blocks: [3]
      window_spec: [8, 4, 6, 3]
      window_pos_embed_bkg_spatial_size: [7, 7]
    neck:
      d_model: 64
      backbone_channel_list: [64, 32, 16, 8]
"""


def run(*args):
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            code = main([str(a) for a in args])
        except SystemExit as e:
            code = e.code
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    d = tmp_path_factory.mktemp("sam2")
    spar = d / "spar_tiny.pt"
    torch.save(make_spar_checkpoint(tiny(), 3), spar)
    t = make_checkpoint(variant("t"), 7, video_path_shapes())
    torch.save(t, d / "sam2.1_hiera_tiny.pt")
    yaml_path = d / "tiny_sam2.yaml"
    yaml_path.write_text(TINY_YAML)
    tiny_ck = make_checkpoint(read_sam2_config(str(yaml_path)), 9)
    torch.save(tiny_ck, d / "tiny_sam2.pt")
    return SimpleNamespace(dir=d, spar=spar, t=t["model"], tiny=tiny_ck["model"], yaml=yaml_path)


# ------------------------------------------------------------------------------ variants
@pytest.mark.parametrize("name,tensors,params", [("hiera_l", 725, 216_651_936), ("hiera_t", 293, 31_167_792)])
def test_variant_tensors_are_the_official_ones(name, tensors, params):
    cfg = variant(name)
    official = official_keys(name)
    used, discarded = used_tensors(cfg), discarded_tensors(cfg)
    unused = {k for k in official if is_unused(k)}
    assert set(used) | set(discarded) | unused == set(official)
    assert not set(used) & set(discarded) and not (set(used) | set(discarded)) & unused
    for k, s in list(used.items()) + list(discarded.items()):
        assert official[k] == s, k
    assert len(used) == tensors and sum(math.prod(s) for s in used.values()) == params
    assert len(discarded) == 12 and len(unused) == 166


def test_official_configs():
    # the official configs/sam2.1 values (7x7 background for t, s, l; 14x14 for b+)
    assert variant("sam2.1_hiera_t").window_pos_embed_bkg_spatial_size == [7, 7]
    assert variant("s").stages == [1, 2, 11, 2] and variant("s").global_att_blocks == [7, 10, 13]
    bp = variant("sam2.1_hiera_b+")
    assert (bp.embed_dim, bp.num_heads, bp.stages, bp.window_pos_embed_bkg_spatial_size) == (112, 2, [2, 3, 16, 3], [14, 14])
    assert variant("sam2.1_hiera_large").window_spec == [8, 4, 16, 8]
    # the window lags a block: hiera_l's block 2 (first of stage 2) still has stage 1's 8
    blocks = variant("l").blocks()
    assert [(b["dim"], b["dim_out"], b["heads"], b["window"], b["q_pool"]) for b in blocks[1:4]] == \
        [(144, 144, 2, 8, 0), (144, 288, 4, 8, 1), (288, 288, 4, 4, 0)]
    assert blocks[23]["window"] == 0 and blocks[44]["window"] == 16 and blocks[45]["window"] == 8


def test_image_size_official_in_yaml_smaller_in_json(tmp_path):
    # every official variant runs at 1024, and says so in its packed JSON form
    assert variant("t").image_size == 1024 and variant("t").to_dict()["image_size"] == 1024
    # the engine's JSON form may give a test model a smaller side: maps and prompt follow it
    d = dict(variant("t").to_dict(), image_size=256)
    (tmp_path / "v.json").write_text(json.dumps(d))
    quarter = read_sam2_config(str(tmp_path / "v.json"))
    assert (quarter.image_size, quarter.token_side(), quarter.mask_input_size()) == (256, 64, 64)
    for bad in (1000, 32, 4096, True):  # not four stages of 2x; windows of 8 on 8 tokens; limit; a bool
        with pytest.raises(Sam2ConfigError, match="image_size"):
            Sam2Config(**dict(d, image_size=bad)).validate()
    # an official YAML stays at the predictor's 1024
    p = tmp_path / "v.yaml"
    p.write_text(TINY_YAML.replace("model:\n", "model:\n  image_size: 512\n", 1))
    with pytest.raises(Sam2ConfigError, match="image_size"):
        read_sam2_config(str(p))


@pytest.mark.parametrize("name", list(VARIANTS))
def test_every_official_variant_plans_from_its_shapes(name):
    """s, b+ and l on their shapes: the plan keeps the path, drops the rest, and the variant
    is recognised from the shapes alone."""
    cfg = variant(name)
    shapes = dict(used_tensors(cfg))
    shapes.update(discarded_tensors(cfg))
    shapes.update(video_path_shapes())
    assert sam2_plan.matching_variant(shapes).name == cfg.name
    src = SimpleNamespace(tensors={k: None for k in shapes}, stored=lambda k: k, origin={k: "f: " + k for k in shapes})
    kept, dropped = {}, {}
    sam2_plan.plan(src, cfg, lambda s, k, shape: kept.__setitem__(k, shape), lambda k, why: dropped.__setitem__(k, why))
    assert kept == used_tensors(cfg) and len(dropped) == 12 + 166


# --------------------------------------------------------------------------- conversions
def test_hiera_t_converts_with_only_the_path(work):
    out = work.dir / "with_t.spar"
    rc, so, se = run(work.spar, "--sam2", work.dir / "sam2.1_hiera_tiny.pt", "-o", out)
    assert rc == 0, se
    f = SafetensorsFile(str(out))
    meta = f.metadata
    assert json.loads(meta["components"])["sam2"] is True
    cfg = json.loads(meta["sam2_config"])
    assert cfg["name"] == "sam2.1_hiera_t" and cfg["window_pos_embed_bkg_spatial_size"] == [7, 7]
    rec = json.loads(meta["conversion"])
    assert rec["sam2_config_from"] == "the file name"
    names = [n for n in f.keys() if n.startswith("sam2.")]
    assert sorted(names) == sorted("sam2." + k for k in used_tensors(variant("t")))
    for n in names:
        np.testing.assert_array_equal(f.get(n), work.t[n[len("sam2."):]].numpy(), err_msg=n)
    assert not any("pred_obj_score_head" in n or "hypernetworks_mlps.0." in n or "memory" in n for n in names)
    dropped = rec["dropped"]
    assert sum(1 for k in dropped if k.startswith("sam2.1_hiera_tiny.pt: ")) == 12 + 166
    assert "SAM2 refinement: sam2.1_hiera_t (from the file name), 293 tensors, 31.17 M parameters" in so


def test_yaml_variant_converts_and_fp16_keeps_tokens(work):
    out = work.dir / "with_tiny.spar"
    rc, so, se = run(work.spar, "--sam2", work.dir / "tiny_sam2.pt", "--sam2-config", work.yaml, "--fp16", "-o", out)
    assert rc == 0, se
    f = SafetensorsFile(str(out))
    assert json.loads(f.metadata["sam2_config"])["embed_dim"] == 8
    assert f.info("sam2.sam_mask_decoder.mask_tokens.weight").dtype == "F32"
    assert f.info("sam2.sam_mask_decoder.iou_token.weight").dtype == "F32"
    assert f.info("sam2.image_encoder.trunk.blocks.0.attn.qkv.weight").dtype == "F16"
    assert f.info("sam2.image_encoder.trunk.pos_embed").dtype == "F32"
    assert f.info("sam2.sam_prompt_encoder.pe_layer.positional_encoding_gaussian_matrix").dtype == "F32"
    assert not is_matrix("sam2.sam_mask_decoder.obj_score_token.weight", (1, 64))
    # without --sam2-config the tiny file is no official variant: refused, asking for one
    rc, so, se = run(work.spar, "--sam2", work.dir / "tiny_sam2.pt", "-o", work.dir / "no.spar")
    assert rc == 1 and "matches none of the official variants" in se and "--sam2-config" in se
    assert not (work.dir / "no.spar").exists()


def refused(work, sd, *extra, name="bad_sam2.pt"):
    path = work.dir / name
    torch.save({"model": sd}, path)
    out = work.dir / "refused.spar"
    rc, so, se = run(work.spar, "--sam2", path, "--sam2-config", "sam2.1_hiera_t", *extra, "-o", out)
    assert rc == 1 and not out.exists()
    lines = se.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("spar-convert: error: "), se
    return lines[0]


def test_refusals_name_the_tensor(work):
    k = "image_encoder.trunk.blocks.3.attn.qkv.weight"
    bad = dict(work.t)
    bad[k] = torch.zeros(5, 7)
    assert "'%s'" % k in refused(work, bad) and "[5, 7]" in refused(work, bad)
    missing = {x: v for x, v in work.t.items() if x != "no_mem_embed"}
    assert "missing tensor 'no_mem_embed'" in refused(work, missing)
    extra = dict(work.t)
    extra["image_encoder.trunk.blocks.12.norm1.weight"] = torch.ones(768)  # hiera_s has 16 blocks
    assert "blocks.12.norm1.weight" in refused(work, extra) and "not part of sam2.1_hiera_t" in refused(work, extra)
    nan = dict(work.t)
    nan["sam_mask_decoder.conv_s0.bias"] = torch.full((32,), float("nan"))
    assert "sam2.sam_mask_decoder.conv_s0.bias" in refused(work, nan) and "NaN" in refused(work, nan)


def test_bad_options_are_one_line(work, tmp_path):
    for args, words in (
            (("--sam2", work.dir / "nope.pt"), "nope.pt"),
            (("--sam2-config", "sam2.1_hiera_t"), "--sam2-config needs --sam2"),
            (("--sam2", work.dir / "sam2.1_hiera_tiny.pt", "--sam2-config", "hiera_xl"), "unknown SAM2 variant 'hiera_xl'"),
            (("--sam2", work.dir / "sam2.1_hiera_tiny.pt", "--sam2-config", tmp_path / "none.yaml"), "not found")):
        rc, so, se = run(work.spar, *args, "-o", tmp_path / "x.spar")
        assert rc == 1 and words in se and len(se.strip().splitlines()) == 1, se
        assert not (tmp_path / "x.spar").exists()


@pytest.mark.parametrize("change,words", [
    ("      q_pool: 2\n", "trunk.q_pool is not supported"),
    ("      embed_dims: 8\n", "unknown field model.image_encoder.trunk.embed_dims"),
    ("      global_att_blocks: [9]\n", "global_att_blocks: block 9 is outside the 6 blocks"),
])
def test_yaml_fields_checked(tmp_path, change, words):
    text = TINY_YAML.replace("      num_heads: 1\n", "      num_heads: 1\n" + change)
    if "global_att_blocks: [9]" in change:
        text = text.replace("      global_att_blocks: [3]\n", "")
    p = tmp_path / "v.yaml"
    p.write_text(text)
    with pytest.raises(Sam2ConfigError, match=words.replace("[", r"\[").replace("]", r"\]")):
        read_sam2_config(str(p))
    # the neck's channels must be the trunk's stage widths
    p.write_text(TINY_YAML.replace("[64, 32, 16, 8]", "[64, 32, 16, 9]"))
    with pytest.raises(Sam2ConfigError, match="backbone_channel_list"):
        read_sam2_config(str(p))
