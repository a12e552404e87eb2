#!/usr/bin/python3
"""Tests of spar_convert.safetensors_file: round trips, atomic writes, the reader's refusals."""

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from spar_convert.safetensors_file import (
    SafetensorsError, SafetensorsFile, SafetensorsWriter, TensorSpec, read_safetensors,
    write_safetensors)

rng = np.random.default_rng(0)


def sample_tensors():
    return {
        "f32": rng.standard_normal((3, 5)).astype(np.float32),
        "f16": rng.standard_normal((7,)).astype(np.float16),
        "f64": rng.standard_normal((2, 2, 2)),
        "i64": rng.integers(-2**40, 2**40, (4,), dtype=np.int64),
        "i32": rng.integers(-2**30, 2**30, (3, 1), dtype=np.int32),
        "u8": rng.integers(0, 255, (5,), dtype=np.uint8),
        "bool": rng.random((2, 3)) > 0.5,
        "scalar": np.array(2.5, dtype=np.float32),
        "empty": np.zeros((0, 3), dtype=np.float32),
        "odd": np.arange(3, dtype=np.uint8),  # makes the next tensor start unaligned
        "after_odd": np.arange(6, dtype=np.float32).reshape(2, 3),
        "transposed": np.arange(12, dtype=np.float32).reshape(3, 4).T,  # not C-contiguous
        "big_endian": np.arange(4, dtype=">i4"),
    }


def leftovers(directory, keep):
    return sorted(p.name for p in Path(directory).iterdir() if p.name not in keep)


def test_round_trip(tmp_path):
    tensors = sample_tensors()
    path = tmp_path / "model.safetensors"
    write_safetensors(path, tensors, {"format_version": "1", "config": '{"depth": 12}'})
    assert leftovers(tmp_path, {"model.safetensors"}) == []

    raw = path.read_bytes()
    (n,) = struct.unpack("<Q", raw[:8])
    assert n % 8 == 0 and (8 + n) % 64 == 0
    header = json.loads(raw[8:8 + n])
    assert list(header)[0] == "__metadata__"
    assert header["f32"] == {"dtype": "F32", "shape": [3, 5], "data_offsets": [0, 60]}
    assert header["big_endian"]["dtype"] == "I32"

    with SafetensorsFile(path) as f:
        assert f.metadata == {"format_version": "1", "config": '{"depth": 12}'}
        assert f.names == list(tensors)
        assert f.info("u8").dtype == "U8" and f.info("u8").shape == (5,)
        for name, want in tensors.items():
            got = f[name]
            assert got.shape == want.shape
            assert got.dtype == want.dtype.newbyteorder("<") or got.dtype == want.dtype
            np.testing.assert_array_equal(got, want)
            assert not got.flags["WRITEABLE"]
        assert "f32" in f and "nope" not in f and len(f) == len(tensors)
        with pytest.raises(SafetensorsError, match="no tensor 'nope'"):
            f["nope"]
    # The raw little-endian bytes of the big-endian input.
    begin, end = header["big_endian"]["data_offsets"]
    assert raw[8 + n + begin:8 + n + end] == np.arange(4, dtype="<i4").tobytes()

    arrays, metadata = read_safetensors(path)
    assert metadata["format_version"] == "1"
    for name, want in tensors.items():
        np.testing.assert_array_equal(arrays[name], want)
        assert arrays[name].flags["WRITEABLE"]


def test_bf16_and_no_metadata(tmp_path):
    bits = np.array([0x3F80, 0xC000, 0x7F80, 0x0001], dtype=np.uint16)
    path = tmp_path / "bf16.safetensors"
    write_safetensors(path, [TensorSpec("w", "BF16", bits.shape, bits)])
    with SafetensorsFile(path) as f:
        assert f.metadata == {}
        assert f.info("w").dtype == "BF16"
        np.testing.assert_array_equal(f["w"], bits)


def test_empty_file_and_only_empty_tensors(tmp_path):
    path = tmp_path / "nothing.safetensors"
    write_safetensors(path, {}, {"a": "b"})
    with SafetensorsFile(path) as f:
        assert f.names == [] and f.metadata == {"a": "b"}
    path = tmp_path / "zero.safetensors"
    write_safetensors(path, {"z": np.zeros((2, 0), dtype=np.int64)})
    assert SafetensorsFile(path)["z"].shape == (2, 0)


def test_streaming_fetches_one_tensor_at_a_time(tmp_path):
    path = tmp_path / "stream.safetensors"
    events = []

    def producer(i):
        def make():
            events.append(("make", i, path.exists()))
            return np.full((1000,), i, dtype=np.float32)
        return make

    specs = [TensorSpec("t%d" % i, "F32", (1000,), producer(i)) for i in range(5)]
    write_safetensors(path, specs)
    assert [e[1] for e in events] == list(range(5))
    assert not any(e[2] for e in events)  # the target appears only at the end
    with SafetensorsFile(path) as f:
        for i in range(5):
            assert (f["t%d" % i] == i).all()


def test_exception_mid_write_leaves_nothing(tmp_path):
    path = tmp_path / "model.safetensors"

    def fail():
        raise RuntimeError("conversion failed")

    specs = [TensorSpec("a", "F32", (4,), np.ones(4, np.float32)),
             TensorSpec("b", "F32", (4,), fail)]
    with pytest.raises(RuntimeError, match="conversion failed"):
        write_safetensors(path, specs)
    assert leftovers(tmp_path, set()) == []

    # An existing file is kept as it was.
    write_safetensors(path, {"old": np.arange(3, dtype=np.int32)})
    before = path.read_bytes()
    with pytest.raises(RuntimeError):
        write_safetensors(path, specs)
    assert path.read_bytes() == before
    assert leftovers(tmp_path, {"model.safetensors"}) == []

    # The same with the writer used directly.
    with pytest.raises(KeyError):
        with SafetensorsWriter(path, [("x", "I64", (2,)), ("y", "I64", (2,))]) as w:
            w.write("x", np.zeros(2, np.int64))
            raise KeyError("boom")
    assert path.read_bytes() == before
    assert leftovers(tmp_path, {"model.safetensors"}) == []


def test_writer_refusals(tmp_path):
    path = tmp_path / "bad.safetensors"
    cases = [
        ([TensorSpec("a", "F32", (2,), np.zeros(3, np.float32))], "shape"),
        ([TensorSpec("a", "F32", (2,), np.zeros(2, np.float64))], "does not match"),
        ([TensorSpec("a", "F32", (2,), None)], "no data"),
        ([TensorSpec("a", "X9", (2,), np.zeros(2))], "unknown dtype"),
        ([TensorSpec("a", "F32", (-1,), np.zeros(2))], "invalid shape"),
        ([TensorSpec("a", "F32", (1,), np.zeros(1, np.float32))] * 2, "listed twice"),
        ([TensorSpec("__metadata__", "F32", (1,), np.zeros(1, np.float32))], "invalid tensor"),
    ]
    for specs, message in cases:
        with pytest.raises(SafetensorsError, match=message):
            write_safetensors(path, specs)
        assert leftovers(tmp_path, set()) == [], message
    with pytest.raises(SafetensorsError, match="metadata"):
        write_safetensors(path, {"a": np.zeros(1)}, {"n": 3})

    w = SafetensorsWriter(path, [("a", "U8", (1,)), ("b", "U8", (1,))])
    with pytest.raises(SafetensorsError, match="expected tensor 'a' next"):
        w.write("b", np.zeros(1, np.uint8))
    w.write("a", np.zeros(1, np.uint8))
    with pytest.raises(SafetensorsError, match="only 1 of 2 tensors"):
        w.commit()
    w.abort()
    assert leftovers(tmp_path, set()) == []


def make_file(path, header, data, header_length=None, pad=True):
    text = json.dumps(header).encode() if not isinstance(header, bytes) else header
    if pad:
        text += b" " * (-len(text) % 8)
    n = len(text) if header_length is None else header_length
    path.write_bytes(struct.pack("<Q", n) + text + data)
    return path


def test_reader_refusals(tmp_path):
    good = {"a": {"dtype": "F32", "shape": [2], "data_offsets": [0, 8]},
            "b": {"dtype": "U8", "shape": [4], "data_offsets": [8, 12]}}
    data = bytes(12)
    make_file(tmp_path / "ok.st", good, data)
    assert SafetensorsFile(tmp_path / "ok.st")["b"].shape == (4,)

    def refused(message, header=good, data=data, **kw):
        path = make_file(tmp_path / "bad.st", header, data, **kw)
        with pytest.raises(SafetensorsError, match=message) as info:
            SafetensorsFile(path)
        assert "\n" not in str(info.value)

    def variant(**changes):
        h = json.loads(json.dumps(good))
        for name, entry in changes.items():
            h[name] = entry
        return h

    refused("exceeds the file", header_length=10**6)
    refused("exceeds the file", header_length=2**64 - 1)
    refused("outside the data area",
            header=variant(b={"dtype": "U8", "shape": [4], "data_offsets": [8, 16]}))
    refused("outside the data area",
            header=variant(b={"dtype": "U8", "shape": [0], "data_offsets": [20, 20]}))
    refused("outside the data area",
            header=variant(b={"dtype": "U8", "shape": [4], "data_offsets": [10, 8]}))
    refused("outside the data area of 10 bytes", data=data[:10])  # truncated data
    refused("4 bytes for U8 \\[5\\], which needs 5",
            header=variant(b={"dtype": "U8", "shape": [5], "data_offsets": [8, 12]}))
    refused("overlap",
            header=variant(b={"dtype": "U8", "shape": [4], "data_offsets": [4, 8]}),
            data=bytes(8))
    refused("belong to no tensor",
            header=variant(b={"dtype": "U8", "shape": [2], "data_offsets": [10, 12]}))
    refused("the data area has 16 bytes but the tensors cover 12", data=bytes(16))
    refused("unknown dtype",
            header=variant(b={"dtype": "Q8", "shape": [4], "data_offsets": [8, 12]}))
    refused("invalid shape",
            header=variant(b={"dtype": "U8", "shape": [-4], "data_offsets": [8, 12]}))
    refused("invalid shape",
            header=variant(b={"dtype": "U8", "shape": [True, 4], "data_offsets": [8, 12]}))
    refused("invalid data_offsets",
            header=variant(b={"dtype": "U8", "shape": [4], "data_offsets": [8]}))
    refused("exactly dtype, shape and data_offsets",
            header=variant(b={"dtype": "U8", "shape": [4], "data_offsets": [8, 12], "x": 1}))
    refused("__metadata__", header=dict(good, __metadata__={"n": 1}))
    refused("not valid JSON", header=b'{"a": ')
    refused("not valid JSON", header=b'{"a": NaN}')
    refused("duplicate key", header=b'{"__metadata__": {}, "__metadata__": {}}')
    refused("does not start with", header=b'[1, 2]  ')
    path = tmp_path / "tiny.st"
    path.write_bytes(b"\x01\x00")
    with pytest.raises(SafetensorsError, match="too short"):
        SafetensorsFile(path)
    with pytest.raises(SafetensorsError, match="cannot read"):
        SafetensorsFile(tmp_path / "missing.st")


def test_truncated_written_file_is_refused(tmp_path):
    path = tmp_path / "model.safetensors"
    write_safetensors(path, sample_tensors())
    raw = path.read_bytes()
    path.write_bytes(raw[:-1])
    with pytest.raises(SafetensorsError, match="outside the data area"):
        SafetensorsFile(path)
    path.write_bytes(raw[:20])
    with pytest.raises(SafetensorsError, match="exceeds the file"):
        SafetensorsFile(path)
