#!/usr/bin/python3
"""safetensors files: a streaming, atomic writer and a validating, memory-mapped reader.

Layout (https://github.com/huggingface/safetensors, "Format"):
    8 bytes      N, unsigned little-endian: length of the header
    N bytes      JSON object, UTF-8: {"__metadata__": {str: str}, NAME: {"dtype": "F32",
                 "shape": [..], "data_offsets": [BEGIN, END]}, ...}, padded with spaces
    rest         the data area: raw little-endian, C-order tensors; offsets are relative to its
                 start, and the tensors cover it exactly (no holes, no overlap)

The writer pads the header so that the data area starts at a multiple of 64 bytes in the file
(the header length stays a multiple of 8), writes the tensors back to back in the order given,
streams them one at a time (each tensor may be produced by a callable just before it is
written), and writes to a temporary file in the target's directory that is renamed over the
target only once everything is written: on any error nothing is left behind.

dtypes: F64 F32 F16 BF16 I64 I32 I16 I8 U64 U32 U16 U8 BOOL. numpy has no bfloat16: BF16 tensors
are written from and read as uint16 arrays of the raw bits.
"""

import collections
import json
import math
import os
import struct
import tempfile

import numpy as np

__all__ = ["SafetensorsError", "TensorSpec", "TensorInfo", "SafetensorsWriter", "SafetensorsFile",
           "write_safetensors", "read_safetensors", "dtype_of", "DTYPES"]


class SafetensorsError(Exception):
    """A safetensors file cannot be written or fails validation. One-line message."""


# safetensors dtype -> numpy dtype of the stored (little-endian) elements
DTYPES = {
    "F64": np.dtype("<f8"),
    "F32": np.dtype("<f4"),
    "F16": np.dtype("<f2"),
    "BF16": np.dtype("<u2"),
    "I64": np.dtype("<i8"),
    "I32": np.dtype("<i4"),
    "I16": np.dtype("<i2"),
    "I8": np.dtype("i1"),
    "U64": np.dtype("<u8"),
    "U32": np.dtype("<u4"),
    "U16": np.dtype("<u2"),
    "U8": np.dtype("u1"),
    "BOOL": np.dtype("?"),
}

_FROM_NUMPY = {dt.newbyteorder("<"): name for name, dt in DTYPES.items() if name != "BF16"}

MAX_HEADER_BYTES = 100_000_000
DATA_ALIGNMENT = 64

TensorSpec = collections.namedtuple("TensorSpec", "name dtype shape data", defaults=(None,))
TensorSpec.__doc__ = """One tensor to write: name, safetensors dtype ("F32", ...), shape, and
data: a numpy array, a zero-argument callable returning one (called only when the tensor is
written), or None when the caller passes arrays to SafetensorsWriter.write itself."""

TensorInfo = collections.namedtuple("TensorInfo", "dtype shape begin end")
TensorInfo.__doc__ = """A tensor of a file: dtype, shape (tuple), and its byte range
[begin, end) relative to the start of the data area."""


def dtype_of(array):
    """The safetensors dtype of a numpy array (uint16 maps to U16: say "BF16" explicitly)."""
    dt = np.dtype(array.dtype if hasattr(array, "dtype") else array)
    name = _FROM_NUMPY.get(dt.newbyteorder("<"))
    if name is None:
        raise SafetensorsError("no safetensors dtype for numpy dtype %s" % dt)
    return name


def _is_int(x):
    return isinstance(x, int) and not isinstance(x, bool)


def _one_line(text):
    return " ".join(str(text).split())


class SafetensorsWriter:
    """Writes a safetensors file tensor by tensor.

        specs = [TensorSpec("a", "F32", (2, 3)), TensorSpec("b", "I64", ())]
        with SafetensorsWriter(path, specs, {"format_version": "1"}) as w:
            w.write("a", a)      # in the order of specs
            w.write("b", b)
        # leaving the block normally renames the finished file over `path`;
        # leaving it with an exception removes the temporary file and leaves `path` untouched.

    metadata: dict of str -> str (the "__metadata__" entry).
    """

    def __init__(self, path, specs, metadata=None):
        self.path = os.fspath(path)
        self._specs = []
        self._fd = None
        self._file = None
        self._tmp = None
        self._next = 0
        self._done = False
        names = set()
        offset = 0
        header = {}
        if metadata:
            if not isinstance(metadata, dict) or not all(
                    isinstance(k, str) and isinstance(v, str) for k, v in metadata.items()):
                raise SafetensorsError("metadata must map strings to strings")
            header["__metadata__"] = dict(metadata)
        for spec in specs:
            name, dtype, shape = spec[0], spec[1], spec[2]
            if not isinstance(name, str) or not name or name == "__metadata__":
                raise SafetensorsError("invalid tensor name %r" % (name,))
            if name in names:
                raise SafetensorsError("tensor %r is listed twice" % name)
            names.add(name)
            if dtype not in DTYPES:
                raise SafetensorsError("tensor %r: unknown dtype %r" % (name, dtype))
            try:
                shape = tuple(shape)
            except TypeError:
                raise SafetensorsError("tensor %r: shape %r is not a sequence"
                                       % (name, shape)) from None
            if not all(_is_int(d) or isinstance(d, np.integer) for d in shape) or \
                    any(d < 0 for d in shape):
                raise SafetensorsError("tensor %r: invalid shape %r" % (name, shape))
            shape = tuple(int(d) for d in shape)
            nbytes = math.prod(shape) * DTYPES[dtype].itemsize
            header[name] = {"dtype": dtype, "shape": list(shape),
                            "data_offsets": [offset, offset + nbytes]}
            self._specs.append((name, dtype, shape, nbytes))
            offset += nbytes
        text = json.dumps(header, separators=(",", ":"), ensure_ascii=True).encode("ascii")
        total = 8 + len(text)
        padded = len(text) + (-total) % DATA_ALIGNMENT
        self._header = struct.pack("<Q", padded) + text + b" " * (padded - len(text))
        self._data_bytes = offset

        directory = os.path.dirname(os.path.abspath(self.path))
        try:
            self._fd, self._tmp = tempfile.mkstemp(
                dir=directory, prefix="." + os.path.basename(self.path) + ".", suffix=".tmp")
            self._file = os.fdopen(self._fd, "wb")
            self._fd = None
            self._file.write(self._header)
        except OSError as e:
            self.abort()
            raise SafetensorsError("cannot write %s: %s" % (self.path, _one_line(e))) from None
        except BaseException:
            self.abort()
            raise

    @property
    def names(self):
        return [s[0] for s in self._specs]

    def write(self, name, array):
        """Writes the next tensor; name must be the next one of the specs, and the array must
        have its shape and a matching dtype (any byte order; BF16 takes uint16 bits)."""
        if self._done or self._file is None:
            raise SafetensorsError("%s: the writer is closed" % self.path)
        if self._next >= len(self._specs):
            raise SafetensorsError("%s: tensor %r was not announced" % (self.path, name))
        spec_name, dtype, shape, nbytes = self._specs[self._next]
        if name != spec_name:
            raise SafetensorsError("%s: expected tensor %r next, got %r"
                                   % (self.path, spec_name, name))
        array = np.asarray(array)
        if tuple(array.shape) != shape:
            raise SafetensorsError("tensor %r: shape %s, announced %s"
                                   % (name, list(array.shape), list(shape)))
        expected = DTYPES[dtype]
        if array.dtype.newbyteorder("<") != expected:
            raise SafetensorsError("tensor %r: numpy dtype %s does not match %s"
                                   % (name, array.dtype, dtype))
        data = np.ascontiguousarray(array, dtype=expected)
        if nbytes:
            try:
                self._file.write(data.reshape(-1).view(np.uint8))
            except OSError as e:
                raise SafetensorsError("cannot write %s: %s" % (self.path, _one_line(e))) from None
        self._next += 1

    def commit(self):
        """Checks that every tensor was written, then renames the file into place."""
        if self._done:
            return
        if self._next != len(self._specs):
            raise SafetensorsError("%s: only %d of %d tensors were written (next: %r)"
                                   % (self.path, self._next, len(self._specs),
                                      self._specs[self._next][0]))
        try:
            self._file.flush()
            if self._file.tell() != len(self._header) + self._data_bytes:
                raise SafetensorsError("%s: wrote %d bytes, expected %d" % (
                    self.path, self._file.tell(), len(self._header) + self._data_bytes))
            os.fsync(self._file.fileno())
            self._file.close()
            self._file = None
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(self._tmp, 0o666 & ~umask)
            os.replace(self._tmp, self.path)
            self._tmp = None
            self._done = True
        except OSError as e:
            self.abort()
            raise SafetensorsError("cannot write %s: %s" % (self.path, _one_line(e))) from None
        except BaseException:
            self.abort()
            raise

    def abort(self):
        """Discards the temporary file (the target is left as it was)."""
        self._done = True
        if self._file is not None:
            try:
                self._file.close()
            except OSError:
                pass
            self._file = None
        if self._fd is not None:
            try:
                os.close(self._fd)
            except OSError:
                pass
            self._fd = None
        if self._tmp is not None:
            try:
                os.unlink(self._tmp)
            except OSError:
                pass
            self._tmp = None

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.commit()
        else:
            self.abort()

    def __del__(self):
        if getattr(self, "_tmp", None) is not None:
            self.abort()


def write_safetensors(path, tensors, metadata=None):
    """Writes a whole file. tensors: a list of TensorSpec (data an array or a zero-argument
    callable returning one, fetched and released one at a time), or a dict name -> array (dtype
    from the array). Atomic: on error the target is left untouched and no temporary remains."""
    if isinstance(tensors, dict):
        specs = []
        for name, array in tensors.items():
            array = np.asarray(array)
            specs.append(TensorSpec(name, dtype_of(array), array.shape, array))
    else:
        specs = [t if isinstance(t, TensorSpec) else TensorSpec(*t) for t in tensors]
    with SafetensorsWriter(path, specs, metadata) as writer:
        for spec in specs:
            data = spec.data() if callable(spec.data) else spec.data
            if data is None:
                raise SafetensorsError("tensor %r has no data" % spec.name)
            writer.write(spec.name, data)
            del data


def _reject_constant(name):
    raise ValueError("JSON constant %s is not allowed" % name)


def _no_duplicates(pairs):
    result = {}
    for key, value in pairs:
        if key in result:
            raise ValueError("duplicate key %r" % key)
        result[key] = value
    return result


class SafetensorsFile:
    """A validated, memory-mapped safetensors file.

        f = SafetensorsFile(path)
        f.metadata            dict str -> str
        f.names               tensor names in header order
        f.info(name)          TensorInfo(dtype, shape, begin, end)
        f[name] / f.get(name) read-only numpy array mapped from the file (BF16 as uint16)

    Everything is checked before any tensor is handed out: the header length lies inside the
    file and below 100 MB, the header is a JSON object (no duplicate keys) with string metadata,
    every entry has exactly dtype/shape/data_offsets, a known dtype, a shape of non-negative
    integers whose element count times the item size equals its byte range, every range lies
    inside the data area, and the ranges cover the data area exactly without overlapping.
    """

    def __init__(self, path):
        self.path = os.fspath(path)
        self._map = None
        try:
            with open(self.path, "rb") as f:
                size = os.fstat(f.fileno()).st_size
                if size < 8:
                    self._fail("file of %d bytes is too short for a header length" % size)
                (n,) = struct.unpack("<Q", f.read(8))
                if n < 2 or n > size - 8:
                    self._fail("header length %d exceeds the file (%d bytes)" % (n, size))
                if n > MAX_HEADER_BYTES:
                    self._fail("header length %d is above the %d limit" % (n, MAX_HEADER_BYTES))
                raw = f.read(n)
        except OSError as e:
            raise SafetensorsError("cannot read %s: %s" % (self.path, _one_line(e))) from None
        if len(raw) != n:
            self._fail("file ended inside the header")
        if raw[:1] != b"{":
            self._fail("header does not start with '{'")
        try:
            header = json.loads(raw.decode("utf-8"), object_pairs_hook=_no_duplicates,
                                parse_constant=_reject_constant)
        except (UnicodeDecodeError, ValueError) as e:
            self._fail("header is not valid JSON (%s)" % _one_line(e))
        if not isinstance(header, dict):
            self._fail("header is not a JSON object")
        self.data_start = 8 + n
        self.data_size = size - self.data_start

        metadata = header.pop("__metadata__", {})
        if metadata is None:
            metadata = {}
        if not isinstance(metadata, dict) or not all(
                isinstance(v, str) for v in metadata.values()):
            self._fail("__metadata__ is not a map of strings to strings")
        self.metadata = metadata

        self._infos = {}
        for name, entry in header.items():
            if not isinstance(entry, dict) or set(entry) != {"dtype", "shape", "data_offsets"}:
                self._fail("tensor %r: entry must have exactly dtype, shape and data_offsets"
                           % name)
            dtype, shape, offsets = entry["dtype"], entry["shape"], entry["data_offsets"]
            if dtype not in DTYPES:
                self._fail("tensor %r: unknown dtype %r" % (name, dtype))
            if not isinstance(shape, list) or not all(_is_int(d) and d >= 0 for d in shape):
                self._fail("tensor %r: invalid shape %r" % (name, shape))
            if not isinstance(offsets, list) or len(offsets) != 2 or \
                    not all(_is_int(o) for o in offsets):
                self._fail("tensor %r: invalid data_offsets %r" % (name, offsets))
            begin, end = offsets
            if not 0 <= begin <= end <= self.data_size:
                self._fail("tensor %r: data_offsets [%d, %d] outside the data area of %d bytes"
                           % (name, begin, end, self.data_size))
            expected = math.prod(shape) * DTYPES[dtype].itemsize
            if end - begin != expected:
                self._fail("tensor %r: %d bytes for %s %s, which needs %d"
                           % (name, end - begin, dtype, shape, expected))
            self._infos[name] = TensorInfo(dtype, tuple(shape), begin, end)

        position = 0
        for name, info in sorted(self._infos.items(), key=lambda kv: (kv[1].begin, kv[1].end)):
            if info.begin < position:
                self._fail("tensor %r: data_offsets [%d, %d] overlap the previous tensor"
                           % (name, info.begin, info.end))
            if info.begin > position:
                self._fail("bytes [%d, %d) of the data area belong to no tensor"
                           % (position, info.begin))
            position = info.end
        if position != self.data_size:
            self._fail("the data area has %d bytes but the tensors cover %d"
                       % (self.data_size, position))
        self.names = list(self._infos)
        if self.data_size > 0:
            self._map = np.memmap(self.path, dtype=np.uint8, mode="r", offset=self.data_start,
                                  shape=(self.data_size,))

    def _fail(self, message):
        raise SafetensorsError("%s: %s" % (self.path, message))

    def info(self, name):
        try:
            return self._infos[name]
        except KeyError:
            raise SafetensorsError("%s: no tensor %r" % (self.path, name)) from None

    def get(self, name):
        info = self.info(name)
        dtype = DTYPES[info.dtype]
        if info.end == info.begin:
            empty = np.zeros(info.shape, dtype=dtype)
            empty.flags.writeable = False
            return empty
        if self._map is None:
            raise SafetensorsError("%s: the file was closed" % self.path)
        return self._map[info.begin:info.end].view(dtype).reshape(info.shape)

    __getitem__ = get

    def __contains__(self, name):
        return name in self._infos

    def __iter__(self):
        return iter(self.names)

    def __len__(self):
        return len(self.names)

    def keys(self):
        return list(self.names)

    def close(self):
        """Drops this object's mapping (arrays already handed out keep theirs alive)."""
        self._map = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def read_safetensors(path):
    """Reads a whole file: (dict name -> array copy, metadata)."""
    with SafetensorsFile(path) as f:
        return {name: np.array(f[name]) for name in f.names}, dict(f.metadata)
