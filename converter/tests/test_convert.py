#!/usr/bin/python3
"""Tests of converter/spar-convert (spar_convert.convert): a tiny SPAR checkpoint made by the
PyTorch reference (perturbed weights, so biases, BatchNorm statistics and the k-bias mask
matter) is converted and the packed file compared with the sources; refusals exit 1 with one
line and leave no file. The converter itself never imports torch (checked in a subprocess).
Conversions run through spar_convert.convert.main in this process (exit code, stdout and stderr
as a subprocess would give them); the script itself runs in subprocesses in test_help and
test_runs_without_torch."""
import gzip
import io
import json
import os
import subprocess
import sys
from contextlib import redirect_stderr, redirect_stdout

import numpy as np
import pytest
import torch
import torch.nn.functional as F

HERE = os.path.dirname(os.path.abspath(__file__))
CONVERTER = os.path.join(HERE, "..")
SCRIPT = os.path.join(CONVERTER, "spar-convert")

from spar_convert.safetensors_file import SafetensorsFile  # noqa: E402
from spar_convert.convert import RUNTIME_FIELDS, is_matrix, main  # noqa: E402
from spar_reference import make_checkpoint, tiny  # noqa: E402
from spar_reference.dino_v3 import DinoV3Backbone  # noqa: E402
from spar_reference.clip_text import CLIPTextEncoder  # noqa: E402

torch.set_num_threads(1)
SEED = 5


def run(*args):
    """spar-convert ARGS through spar_convert.convert.main here: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            code = main([str(a) for a in args])
        except SystemExit as e:     # argparse: usage errors and --help
            code = e.code
    return code, out.getvalue(), err.getvalue()


def run_executable(*args):
    p = subprocess.run([sys.executable, SCRIPT] + [str(a) for a in args], capture_output=True,
                       text=True, timeout=120)
    return p.returncode, p.stdout, p.stderr


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    d = tmp_path_factory.mktemp("convert")
    ckpt = make_checkpoint(tiny(), SEED, perturb=True)
    g = torch.Generator().manual_seed(1)
    # a training checkpoint after the first step also holds the perceptual-loss VGG
    ckpt["model"]["spar_loss_computer._perceptual_loss.vgg.0.weight"] = torch.randn(4, 3, 3, 3, generator=g)
    path = d / "tiny.pt"
    torch.save(ckpt, path)
    return {"dir": d, "ckpt": path, "sd": ckpt["model"]}


def convert(work, name, *extra, expect=0):
    out = work["dir"] / name
    rc, so, se = run(work["ckpt"], "-o", out, *extra)
    assert rc == expect, se
    return out, so, se


def read(path):
    f = SafetensorsFile(str(path))
    meta = f.metadata
    cfg = json.loads(meta["config"])
    rec = json.loads(meta["conversion"])
    return f, meta, cfg, rec


def source_key(name):
    if name.startswith("dino."):
        return "_dino_v3.model." + name[5:]
    if name.startswith("lseg."):
        return "lseg_model." + name[5:]
    return name


def without(d, keys):
    return {k: v for k, v in d.items() if k not in keys}


@pytest.fixture(scope="module")
def f32(work):
    out, so, se = convert(work, "tiny.spar")
    return (out, so) + read(out)


# ----------------------------------------------------------------------------- conversion
def test_metadata_and_inferred_config(f32, work):
    out, so, f, meta, cfg, rec = f32
    assert meta["format"] == "spar-vulkan" and meta["format_version"] == "1"
    want = tiny().to_dict()
    # sizes the tensors do not hold: runtime sizes, and CLIP (this checkpoint carries none)
    skip = set(RUNTIME_FIELDS) | {"clip"}
    assert without(cfg, skip) == without(want, skip)
    assert json.loads(meta["components"]) == {"spar": True, "dino": True, "lseg": True,
                                              "clip": False, "bpe": False}
    # a checkpoint with the tiny preset's sizes takes that preset (as spar-reference does) ...
    assert "configuration the tiny preset" in so and "MB in" in so and "MB out" in so
    # ... and the inference from its tensors, what a checkpoint of no preset gets, agrees
    from types import SimpleNamespace
    from spar_convert.convert import infer_config, read_inputs
    inp = read_inputs(SimpleNamespace(checkpoint=str(work["ckpt"]), dino=None, lseg=None, clip=None, bpe=None))
    try:
        inferred = infer_config(inp, []).validate().to_dict()
    finally:
        inp.close()
    assert without(inferred, skip) == without(want, skip)
    for word in ("kept", "folded", "dropped", "converted"):
        assert word in so


def test_kept_tensors_equal_sources(f32, work):
    out, so, f, meta, cfg, rec = f32
    sd = work["sd"]
    assert rec["kept"]
    for name in rec["kept"]:
        src = sd[source_key(name)].numpy()
        assert f.info(name).dtype == "F32"
        np.testing.assert_array_equal(f.get(name), src, err_msg=name)
    # every tensor of the file is accounted for
    assert set(f.keys()) == set(rec["kept"]) | set(rec["folded"]) | set(rec["packed"])


def test_training_tensors_and_unused_modules_absent(f32):
    out, so, f, meta, cfg, rec = f32
    names = set(f.keys())
    banned = ("spar_loss_computer", "dino_proj", "image_proj", "ray_proj", "running_mean",
              "running_var", "num_batches_tracked", "bias_mask", "static_indicator",
              "dynamic_indicator", "_dino_v3", "lseg_model", "optimizer")
    for n in names:
        assert not any(b in n for b in banned), n
    for n in ("lseg.pretrained.model.head.weight", "lseg.pretrained.model.norm.weight",
              "lseg.scratch.refinenet4.resConfUnit1.conv1.weight", "dino.mask_token",
              "cv_drp.estimator.dpt_decoder.project.1.weight"):
        assert n not in names
    dropped = rec["dropped"]
    assert any("spar_loss_computer" in k for k in dropped)
    assert any("<optimizer>" in k for k in dropped)
    # and everything the engine reads is there
    for n in ("scene_code", "dino.blocks.1.ls2.gamma", "lseg.scratch.head1.weight",
              "semantic_token_decoder.5.weight", "cv_drp.estimator.dpt_decoder.head.bias"):
        assert n in names


def _conv(x, w, b, transposed):
    if transposed:
        return F.conv_transpose2d(x, w, b, stride=w.shape[-1])
    return F.conv2d(x, w, b, padding=w.shape[-1] // 2)


def test_batchnorm_folding_numerically(f32, work):
    out, so, f, meta, cfg, rec = f32
    sd = work["sd"]
    g = torch.Generator().manual_seed(7)
    convs = [n[:-len(".bias")] for n in rec["folded"] if n.endswith(".bias") and "qkv" not in n]
    assert len(convs) == 8 + 14  # CV-DRP decoder + LSeg residual conv units (refinenet4: one)
    for conv in convs:
        src_conv = source_key(conv)
        if conv.startswith("cv_drp"):
            mod, idx = src_conv.rsplit(".", 1)
            bn = "%s.%d" % (mod, int(idx) + 1)
        else:
            bn = src_conv.replace(".conv", ".bn")
        w = sd[src_conv + ".weight"].double()
        b = sd.get(src_conv + ".bias")
        transposed = conv.endswith("up_blocks.0.0") or conv.endswith("up_blocks.1.0") or \
            conv.endswith("up_blocks.2.0") or conv.endswith("final_up.0")
        cin = w.shape[0] if transposed else w.shape[1]
        x = torch.randn(2, cin, 5, 6, generator=g, dtype=torch.float64)
        ref = F.batch_norm(_conv(x, w, None if b is None else b.double(), transposed),
                           sd[bn + ".running_mean"].double(), sd[bn + ".running_var"].double(),
                           sd[bn + ".weight"].double(), sd[bn + ".bias"].double(), False, 0.0, 1e-5)
        fw = torch.from_numpy(f.get(conv + ".weight").astype(np.float64))
        fb = torch.from_numpy(f.get(conv + ".bias").astype(np.float64))
        got = _conv(x, fw, fb, transposed)
        nmse = float(((got - ref) ** 2).sum() / (ref ** 2).sum())
        assert nmse < 1e-12, (conv, nmse)
        assert (b is None) == (conv + ".bias" in rec["created"])


def test_dino_k_bias_mask_folded(f32, work):
    out, so, f, meta, cfg, rec = f32
    sd = work["sd"]
    for i in range(2):
        k = "_dino_v3.model.blocks.%d.attn.qkv." % i
        got = f.get("dino.blocks.%d.attn.qkv.bias" % i)
        np.testing.assert_array_equal(got, (sd[k + "bias"] * sd[k + "bias_mask"]).numpy())
        e = got.shape[0] // 3
        assert np.all(got[e:2 * e] == 0) and np.any(got[:e] != 0)


def test_fp16_halves_the_matrices(f32, work):
    out32, _, f, _, _, _ = f32
    out16, so, _ = convert(work, "tiny16.spar", "--fp16")
    h, meta, cfg, rec = read(out16)
    assert rec["fp16"] is True
    mat32 = mat16 = 0
    for name in f.keys():
        i32, i16 = f.info(name), h.info(name)
        assert i32.shape == i16.shape
        if is_matrix(name, i32.shape):
            assert i16.dtype == "F16", name
            mat32 += i32.end - i32.begin
            mat16 += i16.end - i16.begin
            if name in rec["kept"]:
                np.testing.assert_array_equal(h.get(name), f.get(name).astype(np.float16))
            else:  # folded in float64, rounded once to F16 (F32 file: rounded to F32)
                np.testing.assert_allclose(h.get(name), f.get(name), rtol=1e-3, atol=1e-7)
        else:
            assert i16.dtype == i32.dtype == "F32", name
            np.testing.assert_array_equal(h.get(name), f.get(name))
    assert mat16 * 2 == mat32 and mat32 > 0
    for n in ("scene_code", "decoder_ln.weight", "dino.blocks.0.ls1.gamma", "view_type_embedding.weight",
              "lseg.pretrained.model.pos_embed", "mlp_fuse.1.bias"):
        assert h.info(n).dtype == "F32", n
    assert os.path.getsize(out16) < 0.6 * os.path.getsize(out32)


@pytest.mark.parametrize("kind", ["q8", "q4"])
def test_quantized_weights_layout_and_error(f32, work, kind):
    """--weights q8 / q4 (FORMAT.md "Quantized matrices"): the rule's matrices as codes and
    <name>.qscale, recorded in __metadata__.quantized, format version 2; every value within half a
    step of its block's scale of the fp32 one; all else stored as in the fp32 file."""
    from spar_convert import quantize as q
    from spar_convert.convert import is_quantized, quantized_rows
    out32, _, f, _, _, _ = f32
    outq, _, _ = convert(work, "tiny_%s.spar" % kind, "--weights", kind)
    h, meta, cfg, rec = read(outq)
    assert meta["format_version"] == "2" and rec["weights"] == kind and rec["fp16"] is False
    records = json.loads(meta["quantized"])
    names = [n for n in f.keys() if is_quantized(n, f.info(n).shape)]
    assert sorted(records) == sorted(names) and len(names) > 30
    # LSeg's convolutions by the rule: 3x3 and 1x1 kernels, not the transposed ones
    convs = [n for n in names if len(f.info(n).shape) == 4]
    assert "lseg.pretrained.act_postprocess4.4.weight" in convs and "lseg.pretrained.act_postprocess1.3.weight" in convs
    assert not any(n.startswith("lseg.pretrained.act_postprocess1.4") for n in f.keys() if n in records)
    for name in f.keys():
        i32 = f.info(name)
        if name not in records:
            assert h.info(name).dtype == i32.dtype and h.get(name).tobytes() == f.get(name).tobytes(), name
            continue
        n, k = quantized_rows(i32.shape)  # a convolution kernel as [Cout, Cin*kh*kw]
        assert records[name] == {"bits": q.BITS[kind], "block": 32, "shape": list(i32.shape)}
        codes, scales = h.get(name), h.get(name + ".qscale")
        assert codes.dtype == (np.int8 if kind == "q8" else np.uint8) and codes.shape == ((n, k) if kind == "q8" else (n, k // 2))
        assert scales.dtype == np.float32 and scales.shape == (n, k // 32)
        w = f.get(name).astype(np.float64).reshape(n, k)
        err = np.abs(q.dequantize(codes, scales, kind) - w).reshape(n, k // 32, 32).max(axis=2)
        assert np.all(err <= scales.astype(np.float64) * 0.5 + 1e-12), name
        assert rec["converted"][name].endswith("-> " + kind)
    ratio = os.path.getsize(outq) / os.path.getsize(out32)
    print("%s: %.3f of the fp32 file" % (kind, ratio))
    assert ratio < (0.75 if kind == "q8" else 0.7)  # the tiny model's embeddings and heads stay fp32


def test_quantize_stiff_blocks():
    """One outlier of 1e4 among values of 1e-2 (they become 0), an all-zero block (scale 0, codes
    0), a block of float's smallest normal values: scales finite and the values within half a step."""
    from spar_convert import quantize as q
    w = np.full((2, 96), 1e-2)
    w[:, 5] = 1e4
    w[:, 32:64] = 0.0
    w[:, 64:] = np.finfo(np.float32).tiny * np.arange(32) % 3
    for kind in ("q8", "q4"):
        codes, scales = q.quantize(w, kind)
        assert np.all(np.isfinite(scales)) and np.all(scales[:, 1] == 0)
        d = q.dequantize(codes, scales, kind)
        assert np.all(d[:, 32:64] == 0) and d[0, 5] == pytest.approx(1e4, rel=1e-6)
        assert np.all(np.abs(d - w).reshape(2, 3, 32).max(axis=2) <= scales * 0.5 + 1e-45)
    with pytest.raises(ValueError, match="whole blocks"):
        q.quantize(np.ones((2, 40)), "q8")


def test_fp16_and_other_weights_conflict(work):
    _, _, se = convert(work, "conflict.spar", "--fp16", "--weights", "q8", expect=2)
    assert "--fp16 is --weights fp16" in se
    assert not os.path.exists(os.path.join(work["dir"], "conflict.spar"))


def test_separate_dino_file_overrides(work):
    d = work["dir"]
    other = DinoV3Backbone(tiny().dino, seed=99, perturb=True)
    sd_other = {k: v.clone() for k, v in other.state_dict().items()}
    torch.save(sd_other, d / "dino.pth")
    out, so, se = convert(work, "dino.spar", "--dino", d / "dino.pth")
    f, meta, cfg, rec = read(out)
    assert rec["sources"]["dino"].endswith("dino.pth")
    np.testing.assert_array_equal(f.get("dino.blocks.1.mlp.fc2.weight"),
                                  sd_other["blocks.1.mlp.fc2.weight"].numpy())
    assert not np.array_equal(f.get("dino.blocks.1.mlp.fc2.weight"),
                              work["sd"]["_dino_v3.model.blocks.1.mlp.fc2.weight"].numpy())
    np.testing.assert_array_equal(
        f.get("dino.blocks.0.attn.qkv.bias"),
        (sd_other["blocks.0.attn.qkv.bias"] * sd_other["blocks.0.attn.qkv.bias_mask"]).numpy())
    assert any(v == "overridden by --dino" for v in rec["dropped"].values())
    # a bare SPAR state_dict without _dino_v3.* needs --dino
    bare = {k: v for k, v in work["sd"].items() if not k.startswith("_dino_v3.")}
    torch.save(bare, d / "nodino.pt")
    rc, so, se = run(d / "nodino.pt", "-o", d / "nodino.spar")
    assert rc == 1 and "--dino" in se and not (d / "nodino.spar").exists()
    rc, so, se = run(d / "nodino.pt", "-o", d / "nodino.spar", "--dino", d / "dino.pth")
    assert rc == 0, se


def test_lseg_file_with_clip_bpe_and_bare_state_dict(work):
    """LSeg's own checkpoint (Lightning: state_dict with net.*, CLIP under
    net.clip_pretrained.*), a bare SPAR state_dict without lseg_model.*, and a BPE table."""
    d = work["dir"]
    sd = work["sd"]
    lseg = {"net." + k[len("lseg_model."):]: v for k, v in sd.items() if k.startswith("lseg_model.")}
    clip = CLIPTextEncoder(tiny().clip, seed=3, perturb=True).state_dict()
    for k, v in clip.items():
        lseg["net.clip_pretrained." + k] = v
    lseg["net.clip_pretrained.visual.conv1.weight"] = torch.randn(8, 3, 4, 4)
    lseg["net.clip_pretrained.logit_scale"] = torch.tensor(4.6)
    torch.save({"state_dict": lseg, "epoch": 3}, d / "lseg.ckpt")
    bare = {k: v for k, v in sd.items() if not k.startswith("lseg_model.")}
    torch.save(bare, d / "bare.pt")
    merges = b"#version: 0.2\nt h\nth e</w>\n"
    with gzip.open(d / "merges.txt.gz", "wb") as g:
        g.write(merges)
    out = d / "lsegfile.spar"
    rc, so, se = run(d / "bare.pt", "-o", out, "--lseg", d / "lseg.ckpt", "--bpe",
                     d / "merges.txt.gz")
    assert rc == 0, se
    f, meta, cfg, rec = read(out)
    want = tiny().to_dict()
    assert without(cfg, RUNTIME_FIELDS) == without(want, RUNTIME_FIELDS)
    assert json.loads(meta["components"])["clip"] is True
    for k, v in clip.items():
        np.testing.assert_array_equal(f.get("clip." + k), v.numpy(), err_msg=k)
    np.testing.assert_array_equal(f.get("lseg.scratch.head1.weight"),
                                  sd["lseg_model.scratch.head1.weight"].numpy())
    assert not any("visual" in n or "logit_scale" in n for n in f.keys())
    bpe = f.get("clip.bpe_merges")
    assert f.info("clip.bpe_merges").dtype == "U8"
    assert gzip.decompress(bpe.tobytes()) == merges
    # OpenAI's CLIP state_dict (visual tower, logit_scale, integer entries) overrides LSeg's CLIP
    # (OpenAI's weights are float16: converted to F32)
    openai = {k: v.half() for k, v in CLIPTextEncoder(tiny().clip, seed=4, perturb=True).state_dict().items()}
    openai["visual.proj"] = torch.randn(8, 4)
    openai["logit_scale"] = torch.tensor(4.6)
    openai["context_length"] = torch.tensor(77)
    torch.save(openai, d / "clip.pt")
    out2 = d / "clipfile.spar"
    rc, so, se = run(d / "bare.pt", "-o", out2, "--lseg", d / "lseg.ckpt", "--clip", d / "clip.pt")
    assert rc == 0, se
    f2, meta2, cfg2, rec2 = read(out2)
    for k in clip:
        np.testing.assert_array_equal(f2.get("clip." + k), openai[k].float().numpy(), err_msg=k)
        assert rec2["converted"]["clip." + k] == "float16 -> F32"
    assert rec2["sources"]["clip"].endswith("clip.pt")
    assert any(v == "overridden by --clip" for v in rec2["dropped"].values())
    # no --bpe: a model with a CLIP text encoder gets the repository's merges table
    assert json.loads(meta2["components"])["bpe"]
    with open(REPO_BPE, "rb") as fh:
        assert f2.get("clip.bpe_merges").tobytes() == fh.read()


def test_config_file(work):
    d = work["dir"]
    tiny().save(str(d / "tiny.json"))
    out, so, se = convert(work, "cfg.spar", "--config", d / "tiny.json")
    f, meta, cfg, rec = read(out)
    want = tiny().to_dict()
    assert without(cfg, {"clip"}) == without(want, {"clip"})
    assert rec["config_from"] == "file"
    try:
        import yaml
    except ImportError:
        return
    with open(d / "tiny.yaml", "w") as fh:
        yaml.safe_dump(tiny().to_dict(), fh)
    out, so, se = convert(work, "cfgy.spar", "--config", d / "tiny.yaml")
    assert without(read(out)[2], {"clip"}) == without(want, {"clip"})


REPO_BPE = os.path.join(HERE, "..", "..", "text", "data", "clip", "bpe_simple_vocab_16e6.txt.gz")


def test_real_bpe_table_packed(work):
    path = os.environ.get("SPAR_CLIP_BPE") or REPO_BPE
    out, so, se = convert(work, "bpe.spar", "--bpe", path)
    f = read(out)[0]
    with open(path, "rb") as fh:
        assert f.get("clip.bpe_merges").tobytes() == fh.read()


def test_refuses_bad_bpe(work):
    d = work["dir"]
    (d / "notgz.txt.gz").write_bytes(b"plain text")
    out = d / "badbpe.spar"
    rc, so, se = run(work["ckpt"], "-o", out, "--bpe", d / "notgz.txt.gz")
    assert_refused(rc, se, str(out), "--bpe")


@pytest.mark.filterwarnings("ignore")
def test_clip_from_torchscript_archive(work):
    """OpenAI's ViT-B-32.pt is a TorchScript archive (torch.jit.save): read without torch."""
    d = work["dir"]
    m = CLIPTextEncoder(tiny().clip, seed=6, perturb=True)
    with torch.no_grad():
        traced = torch.jit.trace(m, torch.randint(0, 100, (1, 77)), check_trace=False)
    traced.save(str(d / "clipjit.pt"))
    out = d / "clipjit.spar"
    rc, so, se = run(work["ckpt"], "-o", out, "--clip", d / "clipjit.pt")
    assert rc == 0, se
    f, meta, cfg, rec = read(out)
    assert cfg["clip"] == tiny().clip
    for k, v in m.state_dict().items():
        np.testing.assert_array_equal(f.get("clip." + k), v.numpy(), err_msg=k)


def test_official_yaml_config(work):
    """The official YAML structure (configs/spar/spar.yaml) with tiny sizes; the backbone
    sizes go under the reserved top-level keys dino / lseg."""
    yaml = pytest.importorskip("yaml")
    d = work["dir"]
    t = tiny()
    official = {
        "model": {
            "transformer": {"d": t.d, "d_head": t.d_head, "encoder_n_layer": 2,
                            "encoder_geom_n_layer": 2, "decoder_n_layer": 2, "use_qk_norm": True},
            "cv_drp": {"vit_n_layers": 2, "vit_n_heads": 2, "mask_threshold": 0.5},
            "scene_latent": {"length": 16},
            "pose_latent": {"length": 1, "canonical": "middle", "representation": "6d"},
            "image_tokenizer": {"patch_size": 16, "image_size": 128, "in_channels": 3},
            "target_image": {"patch_size": 16, "height": 128, "width": 128, "in_channels": 6},
            "lseg": {"checkpoint_path": "lseg.ckpt", "feature_dim": 32},
            "dino_v3": {"embed_dim": 64, "arch": "tiny"},
        },
        "training": {"num_views": 5, "num_input_views": 3, "semantic_loss_weight": 0.1},
        "dino": t.dino,
        "lseg": t.lseg,
    }
    with open(d / "spar.yaml", "w") as fh:
        yaml.safe_dump(official, fh)
    out, so, se = convert(work, "official.spar", "--config", d / "spar.yaml")
    cfg = read(out)[2]
    assert without(cfg, {"clip"}) == without(t.to_dict(), {"clip"})
    official["model"]["transformer"]["decoder_n_layer"] = 3
    with open(d / "spar3.yaml", "w") as fh:
        yaml.safe_dump(official, fh)
    out = d / "official3.spar"
    rc, so, se = run(work["ckpt"], "-o", out, "--config", d / "spar3.yaml")
    assert_refused(rc, se, str(out), "missing tensor", "transformer_decoder.2.")


# ----------------------------------------------------------------------------- image size
# tests/python/make_size_model.py: the checkpoint "trained" at 128x128 and its official YAML.
import make_size_model  # noqa: E402


@pytest.fixture(scope="module")
def sized(tmp_path_factory):
    """A photometric tiny SPAR at 128x128 whose DINOv3 is the tiny one (width 64, 2 heads, 2
    blocks: not ViT-B), and the official-format YAML saying 128x128 with dino_v3 arch vitb16."""
    pytest.importorskip("yaml")
    d = tmp_path_factory.mktemp("size")
    cfg = make_size_model.photometric_config()
    make_size_model.write_yaml(str(d / "spar.yaml"), cfg)
    torch.save(make_checkpoint(cfg, 9, perturb=True, optimizer_state=False), d / "size128.pt")
    return {"dir": d, "cfg": cfg, "ckpt": d / "size128.pt", "yaml": d / "spar.yaml"}


def _yaml_variant(sized, name, change):
    import yaml
    y = make_size_model.official_yaml(sized["cfg"])
    change(y)
    path = sized["dir"] / name
    with open(path, "w") as fh:
        yaml.safe_dump(y, fh)
    return path


def test_official_yaml_gives_size_and_dino_tensors_give_heads_depth(sized):
    out = sized["dir"] / "yaml.spar"
    rc, so, se = run(sized["ckpt"], "-o", out, "--config", sized["yaml"])
    assert rc == 0, se
    f, meta, cfg, rec = read(out)
    assert (cfg["image_height"], cfg["image_width"]) == (128, 128)
    assert rec["image_size_from"] == "config"
    # DINOv3 as its tensors are: heads = width / (4 * RoPE periods), depth = blocks; not the
    # 12 heads and 12 blocks of the vitb16 the YAML names
    sd = torch.load(sized["ckpt"])["model"]
    width = sd["_dino_v3.model.cls_token"].shape[-1]
    heads = width // (4 * sd["_dino_v3.model.rope_embed.periods"].numel())
    depth = 1 + max(int(k.split(".")[3]) for k in sd if k.startswith("_dino_v3.model.blocks."))
    assert (width, heads, depth) == (64, 2, 2)
    assert (cfg["dino"]["embed_dim"], cfg["dino"]["num_heads"], cfg["dino"]["depth"]) == \
        (width, heads, depth)
    assert cfg["dino"] == sized["cfg"].dino  # the tiny preset, which these tensors are
    # the rest as the YAML says (it has no lseg section: semantic branch off)
    skip = {"dino", "lseg", "clip", "semantic_dim"}
    assert without(cfg, skip) == without(sized["cfg"].to_dict(), skip)
    lines = se.strip().splitlines()
    assert len(lines) == 1, se
    assert lines[0].startswith("spar-convert: note: DINOv3 sizes from the tensors of ")
    assert "depth 12 -> 2" in lines[0] and "num_heads 12 -> 2" in lines[0]
    assert "image size 128x128 (HxW) from" in so


def test_image_size_rule_is_the_reference_s_and_unknown_size_warns(sized, work):
    from spar_reference.cli import get_config
    # no --config, the tiny preset's tensor sizes: the preset's configuration and 128x128, the
    # size spar-reference renders the same file at (one rule: model_config.matching_preset)
    out = sized["dir"] / "preset.spar"
    rc, so, se = run(work["ckpt"], "-o", out, "-q")
    assert rc == 0 and "warning" not in se, se
    cfg, rec = read(out)[2:]
    assert (cfg["image_height"], cfg["image_width"]) == (128, 128)
    assert (rec["config_from"], rec["image_size_from"]) == ("preset", "config")
    ref = get_config(None, work["sd"], str(work["ckpt"]))
    assert (ref.image_height, ref.image_width) == (128, 128)
    # sizes of no preset (this checkpoint has no semantic branch): the official default, said
    # on stderr (even with -q), recorded as such; the reference infers the same size
    d, ck = sized["dir"], sized["ckpt"]
    assert get_config(None, torch.load(ck)["model"], str(ck)).image_height == 256
    out = d / "nosize.spar"
    rc, so, se = run(ck, "-o", out, "-q")
    assert rc == 0, se
    lines = se.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("spar-convert: warning: the image size is not "
                                                   "known"), se
    assert "stored the default 256x256" in lines[0] and "--size HxW" in lines[0]
    cfg, rec = read(out)[2:]
    assert (cfg["image_height"], cfg["image_width"]) == (256, 256)
    assert rec["image_size_from"] == "default"
    # an official YAML without the size: the same warning, naming the file
    nosize = _yaml_variant(sized, "nosize.yaml", lambda y: (
        y["model"]["target_image"].pop("height"), y["model"]["target_image"].pop("width"),
        y["model"]["image_tokenizer"].pop("image_size")))
    rc, so, se = run(ck, "-o", d / "nosize2.spar", "-q", "--config", nosize)
    assert rc == 0 and "nosize.yaml names none" in se and "256x256" in se, se
    # --size: no warning, non-square allowed, height first
    out = d / "flag.spar"
    rc, so, se = run(ck, "-o", out, "-q", "--size", "64x96")
    assert rc == 0 and se == "", se
    cfg, rec = read(out)[2:]
    assert (cfg["image_height"], cfg["image_width"]) == (64, 96)
    assert rec["image_size_from"] == "--size"
    # --size over the YAML's, with a note
    out = d / "flagyaml.spar"
    rc, so, se = run(ck, "-o", out, "-q", "--config", sized["yaml"], "--size", "64x64")
    assert rc == 0 and "--size 64x64 replaces the 128x128 of" in se, se
    assert read(out)[2]["image_height"] == 64


def test_refuses_unusable_image_sizes(sized):
    d, ck = sized["dir"], sized["ckpt"]
    out = d / "bad.spar"
    rc, so, se = run(ck, "-o", out, "--size", "100x128")
    assert_refused(rc, se, str(out), "image size 100x128 is not a multiple of the patch size 16")
    rc, so, se = run(ck, "-o", out, "--size", "128")  # not HxW: argparse's usage error
    assert rc == 2 and "--size" in se and not out.exists()
    both = _yaml_variant(sized, "both.yaml", lambda y: y["model"]["target_image"].update(height=96))
    rc, so, se = run(ck, "-o", out, "--config", both)
    assert_refused(rc, se, str(out), "image_tokenizer.image_size 128 and target_image 96x128 differ")


def test_dino_tensors_that_do_not_fit_are_refused(sized):
    """Tensors win over the YAML for DINOv3's own sizes, not over SPAR's: a DINOv3 wider than
    D, or with another patch size, cannot feed CV-DRP."""
    d, ck = sized["dir"], sized["ckpt"]
    for name, change, words in [
            ("wide", dict(embed_dim=128), ("cls_token", "[1, 1, 128]", "[1, 1, 64]")),
            ("patch8", dict(patch_size=8), ("DINO patch size must equal patch_size",))]:
        other = DinoV3Backbone(dict(sized["cfg"].dino, **change), seed=3)
        torch.save(other.state_dict(), d / ("%s.pth" % name))
        out = d / ("%s.spar" % name)
        rc, so, se = run(ck, "-o", out, "--config", sized["yaml"], "--dino", d / ("%s.pth" % name))
        assert_refused(rc, se, str(out), *words)


# ----------------------------------------------------------------------------- refusals
def assert_refused(rc, se, out, *words):
    assert rc == 1
    lines = se.strip().splitlines()
    assert len(lines) == 1, se
    assert lines[0].startswith("spar-convert: error: "), se
    assert "Traceback" not in se
    for w in words:
        assert w in lines[0], (w, se)
    assert not os.path.exists(out)
    assert not [n for n in os.listdir(os.path.dirname(out)) if n.endswith(".tmp")]


def test_refuses_config_with_another_d(work):
    d = work["dir"]
    c = tiny().to_dict()
    c["d"] = 128
    c["dino"]["embed_dim"] = 128
    with open(d / "d128.json", "w") as fh:
        json.dump(c, fh)
    out = d / "d128.spar"
    rc, so, se = run(work["ckpt"], "-o", out, "--config", d / "d128.json")
    assert_refused(rc, se, str(out), "scene_code", "[16, 64]", "[16, 128]")


@pytest.mark.parametrize("key", [
    "transformer_decoder.1.mlp.mlp.2.weight",
    "_dino_v3.model.blocks.1.norm1.weight",          # the last layer's first tensor
    "cv_drp.estimator.dpt_decoder.up_blocks.1.4.running_var",
    "lseg_model.scratch.refinenet2.resConfUnit1.bn2.weight",
    "semantic_token_decoder.5.weight",
    "semantic_proj.weight",
    "pe_embedder.2.bias",
])
def test_refuses_missing_tensor(work, key):
    d = work["dir"]
    sd = dict(work["sd"])
    del sd[key]
    torch.save({"model": sd}, d / "missing.pt")
    out = d / "missing.spar"
    rc, so, se = run(d / "missing.pt", "-o", out)
    assert_refused(rc, se, str(out), "missing tensor", "'%s'" % key)


def test_refuses_layers_beyond_config(work):
    d = work["dir"]
    c = tiny()
    c.decoder_n_layer = 1
    c.save(str(d / "dec1.json"))
    out = d / "dec1.spar"
    rc, so, se = run(work["ckpt"], "-o", out, "--config", d / "dec1.json")
    assert_refused(rc, se, str(out), "transformer_decoder.1.", "beyond")


def test_refuses_bad_dtype(work):
    d = work["dir"]
    sd = dict(work["sd"])
    sd["mlp_fuse.1.bias"] = sd["mlp_fuse.1.bias"].to(torch.int32)
    torch.save({"model": sd}, d / "dtype.pt")
    out = d / "dtype.spar"
    rc, so, se = run(d / "dtype.pt", "-o", out)
    assert_refused(rc, se, str(out), "mlp_fuse.1.bias", "int32")


def test_refuses_corrupt_file_and_keeps_old_output(work):
    d = work["dir"]
    data = open(work["ckpt"], "rb").read()
    with open(d / "corrupt.pt", "wb") as fh:
        fh.write(data[: len(data) // 2])
    out = d / "corrupt.spar"
    rc, so, se = run(d / "corrupt.pt", "-o", out)
    assert_refused(rc, se, str(out))
    with open(d / "garbage.pt", "wb") as fh:
        fh.write(b"not a checkpoint at all" * 100)
    rc, so, se = run(d / "garbage.pt", "-o", out)
    assert_refused(rc, se, str(out))
    # a failure leaves an existing output untouched
    out.write_bytes(b"old")
    rc, so, se = run(d / "garbage.pt", "-o", out)
    assert rc == 1 and out.read_bytes() == b"old"
    out.unlink()


def test_refuses_values_beyond_fp16(work):
    d = work["dir"]
    sd = dict(work["sd"])
    w = sd["transformer_encoder.0.mlp.mlp.0.weight"].clone()
    w[0, 0] = 1e5
    sd["transformer_encoder.0.mlp.mlp.0.weight"] = w
    torch.save({"model": sd}, d / "big.pt")
    out = d / "big.spar"
    rc, so, se = run(d / "big.pt", "-o", out, "--fp16")
    assert_refused(rc, se, str(out), "transformer_encoder.0.mlp.mlp.0.weight", "float16")
    rc, so, se = run(d / "big.pt", "-o", out)  # fine in F32
    assert rc == 0, se


# ----------------------------------------------------------------------------- no torch
def test_runs_without_torch(work):
    d = work["dir"]
    out = d / "notorch.spar"
    code = ("import runpy, sys; sys.modules['torch'] = None; "
            "sys.argv = ['spar-convert', %r, '-o', %r, '-q']; "
            "import builtins; real = builtins.__import__\n"
            "def guard(name, *a, **k):\n"
            "    if name == 'torch' or name.startswith('torch.'): raise ImportError('torch imported')\n"
            "    return real(name, *a, **k)\n"
            "builtins.__import__ = guard\n"
            "try:\n    runpy.run_path(%r, run_name='__main__')\n"
            "except SystemExit as e:\n    sys.exit(e.code)\n") % (str(work["ckpt"]), str(out), SCRIPT)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert out.exists()


def test_help():
    rc, so, se = run_executable("--help")
    assert rc == 0 and "--fp16" in so and "--dino" in so and "--bpe" in so


# ----------------------------------------------------------------------------- model card
CARD = {"kind": "demonstration", "about": "trained here for a minute, it renders grey",
        "measured": {"what": "held-out K=3", "psnr_db": 18.14, "baseline": "copying the nearest input",
                     "baseline_psnr_db": 20.02}}


def test_model_card_is_stored_and_replaced_alone(f32, work, tmp_path):
    card = tmp_path / "card.json"
    card.write_text(json.dumps(CARD))
    out, _, _ = convert(work, "carded.spar", "--model-card", card)
    assert json.loads(read(out)[1]["model_card"]) == CARD
    assert "model_card" not in f32[3]  # a conversion without --model-card stores none
    # a packed model in: every tensor byte for byte, the other metadata kept, the card replaced
    other = dict(CARD, about="something else", training={"data": "three rooms", "steps": 2400, "minutes": 80.5})
    card.write_text(json.dumps(other))
    again = tmp_path / "again.spar"
    rc, so, se = run(f32[0], "--model-card", card, "-o", again)
    assert rc == 0, se
    assert "model card (demonstration) replaced" in so
    a, b = SafetensorsFile(str(f32[0])), SafetensorsFile(str(again))
    assert a.names == b.names
    for n in a.names:
        assert a.info(n).dtype == b.info(n).dtype and np.array_equal(a[n], b[n]), n
    assert dict(b.metadata, model_card=None) == dict(a.metadata, model_card=None)
    assert json.loads(b.metadata["model_card"]) == other


@pytest.mark.parametrize("card, words", [
    ("{", "cannot read model card"),
    ([1], "a model card is a JSON object"),
    (dict(CARD, kind="official"), "kind must be one of demonstration"),
    (dict(CARD, about=""), "about must be a non-empty one-line string"),
    (dict(CARD, colour="red"), "unknown field 'colour'"),
    (dict(CARD, measured=dict(CARD["measured"], psnr_db=float("nan"))), "measured.psnr_db must be a finite number"),
    (dict(CARD, measured={"what": "x"}), "measured must have exactly"),
    (dict(CARD, training={"data": "rooms", "steps": 10}), "training must have exactly data, steps, minutes"),
    (dict(CARD, training={"data": "rooms", "steps": 0, "minutes": 1.0}), "training.steps must be a positive integer"),
    (dict(CARD, training={"data": "rooms", "steps": 5, "minutes": float("inf")}), "training.minutes must be a finite"),
])
def test_model_card_refusals_are_one_line(f32, tmp_path, card, words):
    path = tmp_path / "card.json"
    path.write_text(card if isinstance(card, str) else json.dumps(card))
    out = tmp_path / "out.spar"
    rc, so, se = run(f32[0], "--model-card", path, "-o", out)  # read before the input is opened
    assert rc == 1 and se.count("\n") == 1 and words in se, se
    assert not out.exists()


def test_packed_input_takes_only_a_model_card(f32, tmp_path):
    out = tmp_path / "out.spar"
    rc, _, se = run(f32[0], "-o", out)
    assert rc == 1 and "is a packed model already: give --model-card" in se and se.count("\n") == 1, se
    card = tmp_path / "card.json"
    card.write_text(json.dumps(CARD))
    rc, _, se = run(f32[0], "--model-card", card, "--fp16", "-o", out)
    assert rc == 1 and "only --model-card applies to it, not --fp16" in se, se
    rc, _, se = run(tmp_path / "missing.json", "--model-card", card, "-o", out)
    assert rc == 1 and se.count("\n") == 1, se
    assert not out.exists()
