#!/usr/bin/python3
"""Tests of spar_convert.torch_checkpoint against checkpoints written by torch.save."""

import argparse
import collections
import os
import pickletools
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

CONVERTER = Path(__file__).resolve().parents[1]

from spar_convert.torch_checkpoint import (  # noqa: E402
    CheckpointError, TensorRef, load_state_dict, open_checkpoint, open_torchscript, main)

torch.manual_seed(0)


def expected_numpy(t):
    t = t.detach()
    if t.dtype == torch.bfloat16:
        return t.float().numpy()
    return t.numpy()


def assert_same(ref, t):
    """ref: a TensorRef; t: the tensor torch.load returned for it."""
    assert isinstance(ref, TensorRef)
    assert ref.shape == tuple(t.shape)
    assert ref.strides == tuple(t.stride())
    assert ref.storage_offset == t.storage_offset()
    got = ref.numpy()
    want = expected_numpy(t)
    assert got.dtype == want.dtype
    assert got.shape == want.shape
    assert got.flags["C_CONTIGUOUS"] and got.flags["WRITEABLE"]
    np.testing.assert_array_equal(got, want)
    if want.dtype.kind == "f":  # bit-exact, also for -0.0 and NaN
        assert got.tobytes() == np.ascontiguousarray(want).tobytes()


def rewrite_zip(src, dst, changes, drop=(), add=None, compression=zipfile.ZIP_STORED):
    """Copies the zip src to dst, replacing members: changes maps a member name suffix to new
    bytes or to a function of the old bytes; members ending in a suffix of drop are left out;
    add maps names relative to the archive folder to the bytes of new members."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", compression) as zout:
        prefix = zin.namelist()[0].split("/")[0] + "/"
        for info in zin.infolist():
            if any(info.filename.endswith(suffix) for suffix in drop):
                continue
            data = zin.read(info)
            for suffix, change in changes.items():
                if info.filename.endswith(suffix):
                    data = change(data) if callable(change) else change
            zout.writestr(info.filename, data)
        for name, data in (add or {}).items():
            zout.writestr(prefix + name, data)


def test_dtypes_round_trip(tmp_path):
    sd = {
        "f32": torch.randn(3, 5),
        "f16": torch.randn(4, 7).half(),
        "bf16": torch.randn(6, 2).bfloat16(),
        "f64": torch.randn(5, dtype=torch.float64),
        "i64": torch.randint(-2**40, 2**40, (3, 4), dtype=torch.int64),
        "i32": torch.randint(-2**30, 2**30, (9,), dtype=torch.int32),
        "i16": torch.randint(-2**14, 2**14, (2, 2), dtype=torch.int16),
        "i8": torch.randint(-128, 127, (5,), dtype=torch.int8),
        "u8": torch.randint(0, 255, (2, 3, 4), dtype=torch.uint8),
        "bool": torch.rand(3, 3) > 0.5,
        "scalar": torch.tensor(3.25),
        "empty": torch.zeros(0, 4),
        "special": torch.tensor([0.0, -0.0, float("inf"), float("-inf"), float("nan"), 1e-45]),
        "bf16_special": torch.tensor([1e38, -3e-39, float("inf"), 0.1]).bfloat16(),
    }
    path = tmp_path / "dtypes.pt"
    torch.save(sd, path)
    loaded = torch.load(path)
    refs = load_state_dict(path)
    assert list(refs) == list(sd)
    for name, t in loaded.items():
        assert_same(refs[name], t)
        assert refs[name].name == name
    assert refs["bf16"].dtype == "bfloat16" and refs["bf16"].numpy().dtype == np.float32
    assert refs["f16"].dtype == "float16" and refs["bool"].numpy().dtype == np.bool_
    assert refs["i64"].dtype == "int64"


def test_views_of_one_storage(tmp_path):
    base = torch.randn(6, 10)
    sd = {
        "base": base,
        "transposed": base.t(),
        "stepped": base[1:6:2, 1::3],
        "row": base[2],
        "flat_slice": base.view(-1)[7:20],
        "column": base[:, 4],
        "expanded": base[0:1].expand(3, 10),
        "permuted": base.view(2, 3, 10).permute(2, 0, 1),
    }
    path = tmp_path / "views.pt"
    torch.save(sd, path)
    loaded = torch.load(path)
    refs = load_state_dict(path)
    keys = {r.storage_key for r in refs.values()}
    assert len(keys) == 1
    assert refs["row"].storage_offset == 20 and refs["stepped"].storage_offset == 11
    assert refs["expanded"].strides == (0, 1)
    assert not refs["transposed"].is_contiguous() and refs["base"].is_contiguous()
    for name, t in loaded.items():
        assert_same(refs[name], t)


def test_views_without_their_base(tmp_path):
    # Only views are saved: the storage is the whole base, the views start at offsets.
    base = torch.arange(100, dtype=torch.float32).reshape(10, 10)
    sd = {"a": base[3:7, 2:9:3], "b": base[8:, :].t(), "c": base.view(-1)[55:56]}
    path = tmp_path / "partial.pt"
    torch.save(sd, path)
    loaded = torch.load(path)
    refs = load_state_dict(path)
    assert refs["a"].storage_numel == 100
    for name, t in loaded.items():
        assert_same(refs[name], t)


def test_compressed_records(tmp_path):
    # torch stores records uncompressed; a re-zipped (deflated) checkpoint is read through zipfile.
    base = torch.randn(50, 40)
    sd = {"base": base, "view": base[10:40:3, 5:].t(), "h": torch.randn(7).half()}
    path = tmp_path / "stored.pt"
    torch.save(sd, path)
    deflated = tmp_path / "deflated.pt"
    rewrite_zip(path, deflated, {}, compression=zipfile.ZIP_DEFLATED)
    with zipfile.ZipFile(deflated) as z:
        assert all(i.compress_type == zipfile.ZIP_DEFLATED for i in z.infolist())
    refs = load_state_dict(deflated)
    for name, t in sd.items():
        assert_same(refs[name], t)


def test_parameters_and_tied_weights(tmp_path):
    w = torch.nn.Parameter(torch.randn(4, 3))
    b = torch.nn.Parameter(torch.randn(4), requires_grad=False)
    sd = collections.OrderedDict([("w", w), ("b", b), ("tied", w), ("plain", torch.ones(2))])
    path = tmp_path / "params.pt"
    torch.save(sd, path)
    loaded = torch.load(path)
    refs = load_state_dict(path)
    assert refs["w"].is_parameter and refs["w"].requires_grad
    assert refs["b"].is_parameter and not refs["b"].requires_grad
    assert not refs["plain"].is_parameter
    assert refs["tied"].storage_key == refs["w"].storage_key
    for name, t in loaded.items():
        assert_same(refs[name], t)


class TinyNet(torch.nn.Module):
    def __init__(self):
        super().__init__()
        self.conv = torch.nn.Conv2d(3, 4, 3, padding=1)
        self.bn = torch.nn.BatchNorm2d(4)
        self.norm = torch.nn.LayerNorm(4)
        self.head = torch.nn.Linear(4, 2)
        self.register_buffer("mean", torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1))

    def forward(self, x):
        x = self.bn(self.conv(x - self.mean)).mean(dim=(2, 3))
        return self.head(self.norm(x))


def trained_net():
    net = TinyNet()
    opt = torch.optim.Adam(net.parameters(), lr=1e-3, betas=(0.9, 0.95))
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda step: min(1.0, (step + 1) / 10))
    loss = net(torch.randn(2, 3, 5, 5)).square().sum()
    loss.backward()
    opt.step()
    sched.step()
    return net, opt, sched


def test_official_wrapper_with_adam(tmp_path):
    net, opt, sched = trained_net()
    path = tmp_path / "ckpt_spar_000001.pt"
    torch.save({"model": net.state_dict(), "optimizer": opt.state_dict(),
                "lr_scheduler": sched.state_dict(), "fwdbwd_pass_step": 1,
                "param_update_step": 1}, path)
    loaded = torch.load(path)
    sd = net.state_dict()

    refs = load_state_dict(path)
    assert list(refs) == list(sd)
    for name, t in loaded["model"].items():
        assert_same(refs[name], t)
    assert refs["bn.num_batches_tracked"].dtype == "int64"
    assert refs["bn.num_batches_tracked"].numpy() == 1

    with open_checkpoint(path) as ckpt:
        assert ckpt.key == "model" and ckpt.skipped == {}
        assert ckpt.version == "3"
        assert ckpt.extra["fwdbwd_pass_step"] == 1 and ckpt.extra["param_update_step"] == 1
        assert ckpt.extra["lr_scheduler"]["last_epoch"] == loaded["lr_scheduler"]["last_epoch"]
        opt_state = ckpt.extra["optimizer"]
        assert opt_state["param_groups"][0]["betas"] == (0.9, 0.95)
        assert opt_state["param_groups"][0]["params"] == loaded["optimizer"]["param_groups"][0][
            "params"]
        for index, state in loaded["optimizer"]["state"].items():
            for k, v in state.items():
                assert_same(opt_state["state"][index][k], v)
    with pytest.raises(CheckpointError, match="closed"):
        ckpt.state_dict["conv.weight"].numpy()


def test_bare_module_state_dict(tmp_path):
    net, _, _ = trained_net()
    sd = net.state_dict()
    assert isinstance(sd, collections.OrderedDict)
    path = tmp_path / "bare.pth"
    torch.save(sd, path)
    ckpt = open_checkpoint(path)
    assert ckpt.key is None and ckpt.extra == {}
    assert list(ckpt.state_dict) == list(sd)
    for name, t in torch.load(path).items():
        assert_same(ckpt.state_dict[name], t)
    assert ckpt.state_dict["bn.num_batches_tracked"].numpy().dtype == np.int64
    ckpt.close()


def test_state_dict_key_and_explicit_key(tmp_path):
    sd = {"w": torch.randn(2, 2)}
    path = tmp_path / "lightning.ckpt"
    torch.save({"state_dict": sd, "epoch": 3, "hparams": argparse.Namespace(lr=0.1)}, path)
    ckpt = open_checkpoint(path)
    assert ckpt.key == "state_dict"
    assert ckpt.skipped == {"hparams": ["argparse.Namespace"]}
    assert ckpt.extra == {"epoch": 3}
    assert_same(ckpt.state_dict["w"], sd["w"])
    with pytest.raises(CheckpointError, match="no top-level entry 'teacher'"):
        open_checkpoint(path, key="teacher")


def test_unknown_global_outside_model_is_skipped_inside_is_refused(tmp_path):
    path = tmp_path / "args.pt"
    torch.save({"model": {"w": torch.ones(2)}, "args": argparse.Namespace(depth=12),
                "numpy_step": np.int64(7)}, path)
    ckpt = open_checkpoint(path)
    assert list(ckpt.state_dict) == ["w"]
    assert ckpt.skipped["args"] == ["argparse.Namespace"]
    assert "numpy_step" in ckpt.skipped

    path = tmp_path / "args_in_model.pt"
    torch.save({"model": {"w": torch.ones(2), "cfg": argparse.Namespace(depth=12)}}, path)
    with pytest.raises(CheckpointError, match="argparse.Namespace"):
        load_state_dict(path)

    path = tmp_path / "int_in_model.pt"
    torch.save({"w": torch.ones(2), "n": 3}, path)
    with pytest.raises(CheckpointError, match="'n' is a int, not a tensor"):
        load_state_dict(path)


class Evil:
    def __init__(self, command):
        self.command = command

    def __reduce__(self):
        return (os.system, (self.command,))


class EvilEval:
    def __reduce__(self):
        return (eval, ("__import__('os').system('true')",))


@pytest.mark.parametrize("where", ["optimizer", "model", "bare"])
def test_refuses_os_system(tmp_path, where):
    pwned = tmp_path / "pwned"
    evil = Evil("touch %s" % pwned)
    path = tmp_path / "evil.pt"
    if where == "optimizer":
        torch.save({"model": {"w": torch.ones(2)}, "optimizer": {"state": evil}}, path)
    elif where == "model":
        torch.save({"model": {"w": torch.ones(2), "x": evil}}, path)
    else:
        torch.save(collections.OrderedDict([("w", torch.ones(2)), ("x", evil)]), path)
    # The pickle really does reference os.system (posix.system on Linux).
    with zipfile.ZipFile(path) as z:
        data = z.read([n for n in z.namelist() if n.endswith("/data.pkl")][0])
    assert any(op.name == "GLOBAL" and "system" in arg for op, arg, _ in pickletools.genops(data))
    with pytest.raises(CheckpointError) as info:
        open_checkpoint(path)
    message = str(info.value)
    assert "refusing to load checkpoint" in message and "system" in message
    assert "\n" not in message
    assert not pwned.exists()


def test_refuses_eval_and_other_code(tmp_path):
    path = tmp_path / "eval.pt"
    torch.save({"model": {"w": torch.ones(2)}, "lr_scheduler": EvilEval()}, path)
    with pytest.raises(CheckpointError, match="refusing to load checkpoint: it references "
                                              "builtins.eval"):
        open_checkpoint(path)


def test_truncated_and_corrupt_files(tmp_path):
    path = tmp_path / "good.pt"
    torch.save({"w": torch.randn(64, 64)}, path)
    data = path.read_bytes()

    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match="truncated or corrupt zip") as info:
        load_state_dict(truncated)
    assert "\n" not in str(info.value)

    empty = tmp_path / "empty.pt"
    empty.write_bytes(b"")
    with pytest.raises(CheckpointError, match="not a PyTorch zip checkpoint"):
        load_state_dict(empty)

    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(os.urandom(1000))
    with pytest.raises(CheckpointError, match="not a PyTorch zip checkpoint"):
        load_state_dict(garbage)

    with pytest.raises(CheckpointError, match="cannot open checkpoint"):
        load_state_dict(tmp_path / "missing.pt")

    # A flipped byte inside the tensor data: the CRC check catches it when the record is read.
    refs = load_state_dict(path)
    with zipfile.ZipFile(path) as z:
        info = z.getinfo([n for n in z.namelist() if n.endswith("/data/0")][0])
    with open(path, "rb") as f:
        f.seek(info.header_offset + 28)
        extra_len = int.from_bytes(f.read(2), "little")
    pos = info.header_offset + 30 + len(info.filename.encode()) + extra_len + 100
    flipped = bytearray(data)
    flipped[pos] ^= 0xFF
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(bytes(flipped))
    with pytest.raises(CheckpointError, match="tensor 'w': cannot read storage record"):
        load_state_dict(corrupt)["w"].numpy()
    assert refs["w"].numpy().shape == (64, 64)

    # A broken data.pkl.
    broken = tmp_path / "broken.pt"
    rewrite_zip(path, broken, {"/data.pkl": lambda b: b[: len(b) // 2]})
    with pytest.raises(CheckpointError, match="malformed data.pkl"):
        load_state_dict(broken)


def test_storage_too_short(tmp_path):
    base = torch.randn(8, 16)
    path = tmp_path / "good.pt"
    torch.save({"whole": base, "tail": base[6:, 3:]}, path)
    key = load_state_dict(path)["tail"].storage_key

    short = tmp_path / "short.pt"
    rewrite_zip(path, short, {"/data/" + key: lambda b: b[: len(b) - 8]})
    with pytest.raises(CheckpointError, match=r"tensor 'whole': storage record '.*' is too short"):
        load_state_dict(short)

    # Only the view at the end needs the missing bytes: the error names that tensor.
    path2 = tmp_path / "views.pt"
    torch.save({"head": base[:2], "tail": base[6:, 3:]}, path2)
    key = load_state_dict(path2)["tail"].storage_key
    short2 = tmp_path / "short2.pt"
    rewrite_zip(path2, short2, {"/data/" + key: lambda b: b[: 4 * 16 * 5]})
    with pytest.raises(CheckpointError, match="tensor 'tail'.* too short"):
        load_state_dict(short2)

    missing = tmp_path / "missing_record.pt"
    rewrite_zip(path, missing, {}, drop=["/data/" + key])
    with pytest.raises(CheckpointError, match="storage record .* is missing"):
        load_state_dict(missing)


def test_big_endian_archive(tmp_path):
    sd = {"f": torch.randn(3, 4), "i": torch.arange(5, dtype=torch.int64),
          "h": torch.randn(6).half()}
    path = tmp_path / "little.pt"
    torch.save(sd, path)
    refs = load_state_dict(path)
    swaps = {}
    for name, t in sd.items():
        size = t.element_size()
        swaps["/data/" + refs[name].storage_key] = (
            lambda b, size=size: np.frombuffer(b, dtype="<u%d" % size).byteswap().tobytes())
    big = tmp_path / "big.pt"
    # torch 1.13 writes no byteorder record (newer torch writes "little"): replace or add one.
    rewrite_zip(path, big, swaps, drop=["/byteorder"], add={"byteorder": b"big"})
    ckpt = open_checkpoint(big)
    assert ckpt.byteorder == "big"
    for name, t in sd.items():
        got = ckpt.state_dict[name].numpy()
        assert got.dtype.isnative
        np.testing.assert_array_equal(got, t.numpy())


def test_legacy_format_is_refused(tmp_path):
    path = tmp_path / "legacy.pt"
    torch.save({"w": torch.ones(3)}, path, _use_new_zipfile_serialization=False)
    with pytest.raises(CheckpointError, match="legacy .*not supported"):
        load_state_dict(path)


def test_torchscript_archive_is_refused(tmp_path):
    path = tmp_path / "scripted.pt"
    torch.jit.save(torch.jit.script(torch.nn.Linear(2, 2)), str(path))
    with pytest.raises(CheckpointError, match="TorchScript"):
        load_state_dict(path)


def test_torchscript_archive_with_a_damaged_member_is_refused(tmp_path):
    """Found by test_checkpoint_fuzz: open_torchscript let zipfile's BadZipFile through when the
    local header of its version record was damaged."""
    path = tmp_path / "scripted.pt"
    torch.jit.save(torch.jit.script(torch.nn.Linear(2, 2)), str(path))
    with zipfile.ZipFile(path) as z:
        info = next(i for i in z.infolist() if i.filename.endswith("/version"))
    data = bytearray(path.read_bytes())
    data[info.header_offset:info.header_offset + 4] = b"XXXX"  # the local header's magic
    path.write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match="corrupt zip archive .*Bad magic number"):
        open_torchscript(path)


def last_member_patched(tmp_path, offset, value):
    """A torch.save file whose last central directory entry (its version record) has byte
    `offset` set to `value`."""
    path = tmp_path / "w.pt"
    torch.save({"w": torch.ones(2)}, path)
    data = bytearray(path.read_bytes())
    data[data.rfind(b"PK\x01\x02") + offset] = value
    path.write_bytes(bytes(data))
    return path


# Found by test_checkpoint_fuzz: zipfile's NotImplementedError for an archive that needs a newer
# zip version, and its RuntimeError for an encrypted member, passed through the readers.
@pytest.mark.parametrize("opener", [open_checkpoint, open_torchscript])
def test_unsupported_zip_version_is_refused(tmp_path, opener):
    path = last_member_patched(tmp_path, 6, 127)  # "version needed to extract": 12.7
    with pytest.raises(CheckpointError, match="zip file version 12.7"):
        opener(path)


def test_encrypted_member_is_refused(tmp_path):
    path = last_member_patched(tmp_path, 8, 1)  # general purpose flags: encrypted
    with pytest.raises(CheckpointError, match="version' is encrypted"):
        open_checkpoint(path)


def test_cli(tmp_path, capsys):
    path = tmp_path / "cli.pt"
    torch.save({"model": {"a.weight": torch.ones(2, 3)}, "fwdbwd_pass_step": 5}, path)
    assert main([str(path)]) == 0
    out = capsys.readouterr().out
    assert "a.weight" in out and "[2, 3]" in out
    bad = tmp_path / "bad.pt"
    bad.write_bytes(path.read_bytes()[:100])
    assert main([str(bad)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1


def test_package_does_not_import_torch():
    code = ("import sys, spar_convert.torch_checkpoint, spar_convert.safetensors_file; "
            "assert 'torch' not in sys.modules, 'torch imported'")
    subprocess.run([sys.executable, "-c", code], check=True, env=dict(os.environ, PYTHONPATH=str(CONVERTER)))


# --- Hand-made archives: pickles written opcode by opcode -------------------------------------

def p_str(text):
    data = text.encode()
    return b"X" + len(data).to_bytes(4, "little") + data


def p_int(value):
    if -2**31 <= value < 2**31:
        return b"J" + value.to_bytes(4, "little", signed=True)
    n = (value.bit_length() + 8) // 8
    return b"\x8a" + bytes([n]) + value.to_bytes(n, "little", signed=True)  # LONG1


def p_global(module, name):
    return b"c" + module.encode() + b"\n" + name.encode() + b"\n"


def p_tuple(*items):
    return b"(" + b"".join(items) + b"t"


def p_tensor(key="0", numel=4, offset=0, shape=(4,), stride=(1,), storage="FloatStorage"):
    pid = p_tuple(p_str("storage"), p_global("torch", storage), p_str(key), p_str("cpu"),
                  p_int(numel))
    hooks = p_global("collections", "OrderedDict") + b")R"
    return (p_global("torch._utils", "_rebuild_tensor_v2")
            + p_tuple(pid + b"Q", p_int(offset), p_tuple(*map(p_int, shape)),
                      p_tuple(*map(p_int, stride)), b"\x89", hooks) + b"R")


def p_dict(**entries):
    return b"}(" + b"".join(p_str(k) + v for k, v in entries.items()) + b"u"


def hand_made(path, pickle_bytes, records=None):
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("archive/data.pkl", b"\x80\x02" + pickle_bytes + b".")
        z.writestr("archive/version", b"3\n")
        for key, data in (records or {}).items():
            z.writestr("archive/data/" + key, data)
    return path


def test_hand_made_archive_is_read(tmp_path):
    data = np.arange(6, dtype="<f4").tobytes()
    path = hand_made(tmp_path / "ok.pt", p_dict(a=p_tensor(numel=6, offset=1, shape=(2, 2),
                                                           stride=(1, 2))), {"0": data})
    np.testing.assert_array_equal(load_state_dict(path)["a"].numpy(), [[1, 3], [2, 4]])

    # An unsupported storage type or an unknown tensor subclass outside the model: skipped.
    unknown_subclass = (p_global("torch._tensor", "_rebuild_from_type_v2")
                        + p_tuple(p_global("torch._utils", "_rebuild_tensor_v2"),
                                  p_global("mylib", "MyTensor"), b")", b"}") + b"R")
    path = hand_made(tmp_path / "skip.pt", p_dict(
        model=p_dict(a=p_tensor()), step=p_int(7),
        optimizer=p_dict(q=p_tensor(key="1", storage="QInt8Storage")),
        extra=p_dict(t=unknown_subclass)), {"0": bytes(16), "1": bytes(4)})
    ckpt = open_checkpoint(path)
    assert ckpt.skipped == {"optimizer": ["torch.QInt8Storage"], "extra": ["mylib.MyTensor"]}
    assert ckpt.extra == {"step": 7} and list(ckpt.state_dict) == ["a"]
    ckpt.close()


@pytest.mark.parametrize("payload, message", [
    (p_dict(a=p_global("subprocess", "check_output") + p_tuple(p_str("id")) + b"R"),
     "references subprocess.check_output"),
    (p_dict(a=p_global("torch", "load") + p_tuple(p_str("x.pt")) + b"R"),
     "references torch.load"),
    (p_dict(a=p_global("__builtin__", "getattr") + b")R"), "references builtins.getattr"),
    (p_dict(a=p_tensor(numel=4, offset=0, shape=(4,), stride=(1,))
            + p_dict(storage_offset=p_int(100)) + b"b"), "sets state on a TensorRef"),
    (p_dict(a=p_tensor(shape=(-1,))), "not a tuple of non-negative integers"),
    (p_dict(a=p_tensor(stride=(1, 1))), "differ in length"),
    # Found by test_checkpoint_fuzz: numpy's ValueError for an empty tensor of absurd sizes.
    (p_dict(a=p_tensor(shape=(0, 2**63), stride=(1, 1))), "beyond 64-bit byte offsets"),
    (p_dict(a=p_tensor(shape=(1,), stride=(2**62,))), "beyond 64-bit byte offsets"),
    (p_dict(a=p_tensor(numel=4, offset=2, shape=(3,))), "needs 5 elements of storage '0'"),
    (p_dict(a=p_tensor(storage="QInt8Storage")), "state_dict references torch.QInt8Storage"),
    (p_dict(a=p_tensor(), b=p_tensor(numel=5)), "declared both as 4 float32 and as 5"),
    (p_dict(a=p_global("torch._utils", "_rebuild_tensor_v2")
            + p_tuple(p_global("mylib", "Storage") + b")R", p_int(0), p_tuple(p_int(1)),
                      p_tuple(p_int(1)), b"\x89", b"N") + b"R"),
     "state_dict references mylib.Storage"),
    (b"]q\x00(K\x01e", "the state_dict is a list"),
    # Found by test_checkpoint_fuzz: LONG_BINPUT 359757679 made the C unpickler allocate 3 GB
    # for its memo (9 s); up to 2**32 - 1 it would be tens of GB.
    (b"}r\xff\xff\xff\xff", "memo index 4294967295 at byte 3 is beyond the 2 opcodes"),
])
def test_hand_made_refusals(tmp_path, payload, message):
    path = hand_made(tmp_path / "bad.pt", payload, {"0": bytes(16)})
    with pytest.raises(CheckpointError, match=message) as info:
        load_state_dict(path)
    assert "\n" not in str(info.value)


def test_two_archives_in_one_zip_are_refused(tmp_path):
    path = tmp_path / "two.pt"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("a/data.pkl", b"\x80\x02}.")
        z.writestr("b/data.pkl", b"\x80\x02}.")
    with pytest.raises(CheckpointError, match="not a torch.save checkpoint"):
        load_state_dict(path)
