#!/usr/bin/python3
"""Read PyTorch zip checkpoints (torch.save, format of torch >= 1.6) without torch and without
running any code stored in them.

A torch.save file is a zip archive holding
    <archive>/data.pkl       the pickled object; tensors refer to storages by persistent id
    <archive>/data/<key>     one record per storage: the raw elements
    <archive>/version        serialization version ("3")
    <archive>/byteorder      "little" or "big" (newer torch; absent means little)

data.pkl is read with a restricted unpickler: only the few globals a state_dict needs resolve,
each to a function of this module that builds a lazy `TensorRef` (never to torch's own code).
Globals of modules that can run code or touch the system (os, subprocess, builtins.eval, ...)
make the load fail at once. Any other unknown global becomes an inert placeholder that is never
called; if a placeholder ends up inside the returned state_dict the load fails naming the global,
while a placeholder inside another entry of the training wrapper (optimizer, lr_scheduler, ...)
only drops that entry (reported in `Checkpoint.skipped`).

Tensor data is read on demand, one storage record (or the byte range a view needs) at a time,
so checkpoints of many GB need no more memory than their largest tensor.

Usage:
    sd = load_state_dict("ckpt_spar_0001.pt")        # dict[str, TensorRef]
    w = sd["pose_predictor.proj.weight"].numpy()      # contiguous numpy array

Command line (lists the tensors):  /usr/bin/python3 -m spar_convert.torch_checkpoint FILE [KEY]
"""

import collections
import io
import math
import os
import pickle
import pickletools
import sys
import tarfile
import zipfile
import zlib

import numpy as np

__all__ = ["CheckpointError", "TensorRef", "Checkpoint", "open_checkpoint", "load_state_dict",
           "open_torchscript"]


class CheckpointError(Exception):
    """A checkpoint cannot be read safely or correctly. The message is one line, meant to be
    printed as is (no traceback)."""


# dtype name -> (numpy code of the stored elements, numpy dtype of what .numpy() returns)
_DTYPES = {
    "float64": ("f8", np.float64),
    "float32": ("f4", np.float32),
    "float16": ("f2", np.float16),
    "bfloat16": ("u2", np.float32),  # raw bits; widened to float32 by shifting left 16
    "int64": ("i8", np.int64),
    "int32": ("i4", np.int32),
    "int16": ("i2", np.int16),
    "int8": ("i1", np.int8),
    "uint8": ("u1", np.uint8),
    "bool": ("u1", np.bool_),
}

# torch.<Name>Storage global -> dtype name
_STORAGE_TYPES = {
    "DoubleStorage": "float64",
    "FloatStorage": "float32",
    "HalfStorage": "float16",
    "BFloat16Storage": "bfloat16",
    "LongStorage": "int64",
    "IntStorage": "int32",
    "ShortStorage": "int16",
    "CharStorage": "int8",
    "ByteStorage": "uint8",
    "BoolStorage": "bool",
    "UntypedStorage": "uint8",
}

# Legacy (pre-1.6) torch.save files start with this number pickled with protocol 2.
_LEGACY_MAGIC = b"\x80\x02\x8a\x0a" + (0x1950A86A20F9469CFC6C).to_bytes(10, "little")

# Module roots whose globals can run code, load code or touch the system: refused outright,
# wherever they appear. Everything else unknown becomes an inert placeholder (see module doc).
_DANGEROUS_ROOTS = frozenset("""
    os posix nt posixpath ntpath subprocess sys builtins __builtin__ shutil socket pty
    importlib imp runpy zipimport pkgutil site ctypes _ctypes cffi multiprocessing _posixsubprocess
    pickle _pickle cPickle dill cloudpickle marshal shelve dbm code codeop pdb bdb trace timeit
    cProfile profile webbrowser io _io tempfile pathlib glob platform signal select selectors
    fcntl resource threading _thread asyncio concurrent urllib urllib2 http httplib ftplib
    smtplib telnetlib xmlrpc socketserver ssl pip setuptools distutils operator _operator
    functools _functools types inspect copyreg copy_reg gc weakref zipfile tarfile gzip bz2
    lzma sqlite3 _sqlite3 logging atexit ast compileall py_compile numpy.testing
""".split())

# torch globals that are plain values (harmless as placeholders); every other torch global
# outside the allowlist (torch.load, torch.jit.*, torch.hub.*, ...) is refused outright.
_TORCH_HARMLESS = frozenset("""
    device dtype layout memory_format strided sparse_coo contiguous_format channels_last
    preserve_format float64 double float32 float float16 half bfloat16 int64 long int32 int
    int16 short int8 uint8 bool complex64 complex128 cfloat cdouble
""".split())

_MODULE_ALIASES = {
    "__builtin__": "builtins",
    "copy_reg": "copyreg",
    "torch.tensor": "torch._tensor",
}


# What zipfile raises for a damaged or unsupported archive (NotImplementedError: an unknown
# compression method or zip version; RuntimeError: an encrypted member); the reader turns each
# into a one-line CheckpointError.
_ZIP_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, NotImplementedError,
               RuntimeError)


def _one_line(text):
    return " ".join(str(text).split())


# ---------------------------------------------------------------------------------------------
# Objects the unpickler builds


class _Inert:
    """Base of the objects built while unpickling: no pickle BUILD may modify them."""

    __slots__ = ()

    def __setstate__(self, state):
        raise CheckpointError("malformed checkpoint: data.pkl sets state on a %s"
                              % type(self).__name__.lstrip("_"))


class _StorageType(_Inert):
    """Stands for torch.<X>Storage in data.pkl."""

    __slots__ = ("name", "dtype")

    def __init__(self, name, dtype):
        self.name = name
        self.dtype = dtype

    def __call__(self, *args, **kwargs):
        raise CheckpointError("refusing to load checkpoint: it constructs torch.%s directly"
                              % self.name)


class _TypeMarker(_Inert):
    """Stands for torch.Tensor / torch.nn.Parameter as the new_type of _rebuild_from_type_v2."""

    __slots__ = ("name",)

    def __init__(self, name):
        self.name = name

    def __call__(self, *args, **kwargs):
        raise CheckpointError("refusing to load checkpoint: it calls %s directly" % self.name)


class _Storage(_Inert):
    """One storage record of the archive (not read until a tensor needs it)."""

    __slots__ = ("archive", "key", "dtype", "numel", "location")

    def __init__(self, archive, key, dtype, numel, location):
        self.archive = archive
        self.key = key
        self.dtype = dtype
        self.numel = numel
        self.location = location


class _Unresolved:
    """Base of the inert placeholders for unknown globals. Calling, constructing, building or
    filling one does nothing; the global itself is never imported."""

    global_name = "?"

    def __new__(cls, *args, **kwargs):
        return object.__new__(cls)

    def __init__(self, *args, **kwargs):
        pass

    def __setstate__(self, state):
        pass

    def append(self, item):
        pass

    def extend(self, items):
        pass

    def __setitem__(self, key, value):
        pass

    def __repr__(self):
        return "<unresolved %s>" % self.global_name


class TensorRef(_Inert):
    """A tensor of the checkpoint, not yet read.

    dtype           "float32", "float16", "bfloat16", "float64", "int64", "int32", "int16",
                    "int8", "uint8" or "bool"
    shape, strides  tuples of ints (strides in elements, as torch's Tensor.stride())
    storage_offset  offset of element [0, ..., 0] in the storage, in elements
    storage_key     name of the storage record (tensors sharing a storage share the key)
    storage_numel   number of elements of that storage
    requires_grad, is_parameter   as saved
    name            the state_dict key (set when the checkpoint is opened), or None

    .numpy() reads the storage record (only the byte range the view spans) and returns a new
    C-contiguous array; bfloat16 comes back as float32 (exact), everything else in its own dtype.
    """

    __slots__ = ("_storage", "dtype", "shape", "strides", "storage_offset", "requires_grad",
                 "is_parameter", "name")

    def __init__(self, storage, shape, strides, storage_offset, requires_grad, is_parameter):
        self._storage = storage
        self.dtype = storage.dtype
        self.shape = shape
        self.strides = strides
        self.storage_offset = storage_offset
        self.requires_grad = requires_grad
        self.is_parameter = is_parameter
        self.name = None

    @property
    def storage_key(self):
        return self._storage.key

    @property
    def storage_numel(self):
        return self._storage.numel

    @property
    def numel(self):
        return math.prod(self.shape)

    @property
    def itemsize(self):
        return int(np.dtype(_DTYPES[self.dtype][0]).itemsize)

    @property
    def numpy_dtype(self):
        """The dtype of the array .numpy() returns."""
        return np.dtype(_DTYPES[self.dtype][1])

    def is_contiguous(self):
        expected = 1
        for size, stride in zip(reversed(self.shape), reversed(self.strides)):
            if size != 1 and stride != expected:
                return False
            expected *= size
        return True

    def extent(self):
        """Number of storage elements from storage_offset that the view spans (0 if empty)."""
        if any(s == 0 for s in self.shape):
            return 0
        return 1 + sum((size - 1) * stride for size, stride in zip(self.shape, self.strides))

    def _label(self, name=None):
        name = name if name is not None else self.name
        return "tensor %r" % name if name is not None else "a tensor"

    def check(self, name=None):
        """Checks that the storage record exists, holds every element of the view and has the
        size the checkpoint declares, without reading it. Raises CheckpointError naming the
        tensor."""
        self._check_extent(name)
        self._check_record_size(name)

    def _check_extent(self, name=None):
        st = self._storage
        label = self._label(name)
        extent = self.extent()
        end = self.storage_offset + extent
        if extent and end > st.numel:
            raise CheckpointError(
                "%s: the view (offset %d, shape %s, strides %s) needs %d elements of storage %r, "
                "which declares only %d" % (label, self.storage_offset, list(self.shape),
                                            list(self.strides), end, st.key, st.numel))
        info = st.archive.info(st.key)
        if info is None:
            raise CheckpointError("%s: storage record %r is missing from %s"
                                  % (label, st.archive.record_name(st.key), st.archive.path))
        itemsize = self.itemsize
        if extent and info.file_size < end * itemsize:
            raise CheckpointError(
                "%s: storage record %r is too short: %d bytes, the view needs %d (%d %s elements)"
                % (label, st.archive.record_name(st.key), info.file_size, end * itemsize, end,
                   self.dtype))

    def _check_record_size(self, name=None):
        st = self._storage
        label = self._label(name)
        info = st.archive.info(st.key)
        itemsize = self.itemsize
        if info.file_size != st.numel * itemsize:
            raise CheckpointError(
                "%s: storage record %r holds %d bytes, the checkpoint declares %d %s elements "
                "(%d bytes)" % (label, st.archive.record_name(st.key), info.file_size, st.numel,
                                self.dtype, st.numel * itemsize))

    def numpy(self):
        self.check()
        code, out_dtype = _DTYPES[self.dtype]
        if self.numel == 0:
            return np.zeros(self.shape, dtype=out_dtype)
        st = self._storage
        itemsize = self.itemsize
        start = self.storage_offset * itemsize
        length = self.extent() * itemsize
        data = st.archive.read(st.key, start, length, self._label())
        raw_dtype = np.dtype(("<" if st.archive.byteorder == "little" else ">") + code)
        raw = np.frombuffer(data, dtype=raw_dtype)
        if (raw.flags["WRITEABLE"] and raw_dtype.isnative and self.dtype not in ("bfloat16", "bool")
                and self.is_contiguous() and raw.size == self.numel):
            return raw.reshape(self.shape)  # the freshly read buffer is the result: no copy
        view = np.lib.stride_tricks.as_strided(
            raw, shape=self.shape, strides=tuple(s * itemsize for s in self.strides),
            writeable=False)
        native = np.array(view, dtype=raw_dtype.newbyteorder("="), order="C", copy=True)
        if self.dtype == "bfloat16":
            return (native.astype(np.uint32) << 16).view(np.float32)
        if self.dtype == "bool":
            return native != 0
        return native

    def __repr__(self):
        return "TensorRef(%s%s, shape=%s, strides=%s, offset=%d, storage=%r)" % (
            "" if self.name is None else repr(self.name) + ", ", self.dtype, list(self.shape),
            list(self.strides), self.storage_offset, self.storage_key)


# ---------------------------------------------------------------------------------------------
# Safe replacements of the globals torch.save writes


def _is_int(x):
    return isinstance(x, int) and not isinstance(x, bool)


def _int_tuple(value, what):
    if not isinstance(value, (tuple, list)) or not all(_is_int(v) and v >= 0 for v in value):
        raise CheckpointError("malformed checkpoint: tensor %s is not a tuple of non-negative "
                              "integers: %s" % (what, _one_line(repr(value))[:80]))
    return tuple(int(v) for v in value)


def _unresolved_instance(x):
    """An inert placeholder instance if x is a placeholder class or instance, else None: a
    tensor built from an unknown global is itself unknown (skipped outside the state_dict,
    refused inside it)."""
    if isinstance(x, _Unresolved):
        return x
    if isinstance(x, type) and issubclass(x, _Unresolved):
        return x()
    return None


def _rebuild_tensor(storage, storage_offset, size, stride):
    if not isinstance(storage, _Storage):
        unresolved = _unresolved_instance(storage)
        if unresolved is not None:
            return unresolved
        raise CheckpointError("malformed checkpoint: a tensor's storage is a %s"
                              % type(storage).__name__)
    if not _is_int(storage_offset) or storage_offset < 0:
        raise CheckpointError("malformed checkpoint: tensor storage offset %r" % (storage_offset,))
    shape = _int_tuple(size, "shape")
    strides = _int_tuple(stride, "strides")
    if len(shape) != len(strides):
        raise CheckpointError("malformed checkpoint: tensor shape %s and strides %s differ in "
                              "length" % (list(shape), list(strides)))
    # numpy (like torch) counts bytes in int64: beyond that no array exists, not even an empty
    # one (np.zeros((0, 2**63)) raises ValueError), and no stride can be applied.
    itemsize = np.dtype(_DTYPES[storage.dtype][0]).itemsize
    limit = 2**63 - 1
    if math.prod(d for d in shape if d) * itemsize > limit or any(s * itemsize > limit for s in strides):
        raise CheckpointError("malformed checkpoint: tensor shape %s, strides %s reach beyond 64-bit "
                              "byte offsets" % (list(shape), list(strides)))
    return TensorRef(storage, shape, strides, int(storage_offset), False, False)


def _rebuild_tensor_v2(storage, storage_offset, size, stride, requires_grad=False,
                       backward_hooks=None, metadata=None):
    tensor = _rebuild_tensor(storage, storage_offset, size, stride)
    tensor.requires_grad = bool(requires_grad)
    return tensor


def _rebuild_parameter(data, requires_grad, backward_hooks):
    unresolved = _unresolved_instance(data)
    if unresolved is not None:
        return unresolved
    if not isinstance(data, TensorRef):
        raise CheckpointError("malformed checkpoint: a Parameter wraps a %s" % type(data).__name__)
    param = TensorRef(data._storage, data.shape, data.strides, data.storage_offset,
                      bool(requires_grad), True)
    return param


def _rebuild_parameter_with_state(data, requires_grad, backward_hooks, state):
    return _rebuild_parameter(data, requires_grad, backward_hooks)


_TENSOR_TYPE = _TypeMarker("torch.Tensor")
_PARAMETER_TYPE = _TypeMarker("torch.nn.parameter.Parameter")


def _rebuild_from_type_v2(func, new_type, args, state):
    for x in (func, new_type):
        unresolved = _unresolved_instance(x)
        if unresolved is not None:
            return unresolved
    if func not in (_rebuild_tensor, _rebuild_tensor_v2, _rebuild_parameter,
                    _rebuild_parameter_with_state):
        raise CheckpointError("refusing to load checkpoint: _rebuild_from_type_v2 of %s"
                              % getattr(func, "global_name", type(func).__name__))
    if new_type is not _TENSOR_TYPE and new_type is not _PARAMETER_TYPE:
        raise CheckpointError("refusing to load checkpoint: a tensor of type %s"
                              % getattr(new_type, "global_name", type(new_type).__name__))
    if not isinstance(args, tuple):
        raise CheckpointError("malformed checkpoint: _rebuild_from_type_v2 arguments")
    tensor = func(*args)
    if new_type is _PARAMETER_TYPE and isinstance(tensor, TensorRef):
        tensor.is_parameter = True
    return tensor


def _ordered_dict(items=()):
    od = collections.OrderedDict()
    if items:
        if not isinstance(items, (list, tuple)):
            raise CheckpointError("malformed checkpoint: OrderedDict of a %s"
                                  % type(items).__name__)
        for item in items:
            if not isinstance(item, (list, tuple)) or len(item) != 2:
                raise CheckpointError("malformed checkpoint: OrderedDict item")
            od[item[0]] = item[1]
    return od


def _torch_size(dims=()):
    return _int_tuple(dims, "torch.Size")


def _checked_collection(kind):
    def build(items=()):
        if not isinstance(items, (list, tuple, set, frozenset)):
            raise CheckpointError("malformed checkpoint: %s of a %s" % (kind.__name__,
                                                                        type(items).__name__))
        return kind(items)
    return build


def _codecs_encode(text, encoding="latin1"):
    # Protocol 2 pickles bytes as _codecs.encode(str, "latin1").
    if not isinstance(text, str) or encoding not in ("latin1", "latin-1"):
        raise CheckpointError("refusing to load checkpoint: _codecs.encode with %r"
                              % (encoding,))
    return text.encode("latin1")


_ALLOWED = {
    ("collections", "OrderedDict"): _ordered_dict,
    ("torch._utils", "_rebuild_tensor"): _rebuild_tensor,
    ("torch._utils", "_rebuild_tensor_v2"): _rebuild_tensor_v2,
    ("torch._utils", "_rebuild_parameter"): _rebuild_parameter,
    ("torch._utils", "_rebuild_parameter_with_state"): _rebuild_parameter_with_state,
    ("torch._tensor", "_rebuild_from_type_v2"): _rebuild_from_type_v2,
    ("torch", "Tensor"): _TENSOR_TYPE,
    ("torch._tensor", "Tensor"): _TENSOR_TYPE,
    ("torch.nn.parameter", "Parameter"): _PARAMETER_TYPE,
    ("torch", "Size"): _torch_size,
    ("builtins", "set"): _checked_collection(set),
    ("builtins", "frozenset"): _checked_collection(frozenset),
    ("_codecs", "encode"): _codecs_encode,
}
for _name, _dtype in _STORAGE_TYPES.items():
    _ALLOWED[("torch", _name)] = _StorageType(_name, _dtype)
_ALLOWED[("torch.storage", "UntypedStorage")] = _ALLOWED[("torch", "UntypedStorage")]


def _display_global(module, name):
    full = "%s.%s" % (module, name)
    if module in ("posix", "nt"):
        full += " (os.%s)" % name
    return full


def _is_dangerous(module, name):
    root = module.split(".")[0]
    if root in _DANGEROUS_ROOTS:
        return True
    if root == "torch":
        return not (module == "torch" and (name in _TORCH_HARMLESS or name.endswith("Storage")))
    if root in ("numpy", "scipy", "pandas") and name in ("load", "loads", "fromfile", "loadtxt",
                                                        "genfromtxt", "read_pickle", "eval"):
        return True
    return False


def _check_memo_indices(data):
    """Refuses a memo index beyond the opcodes before it. The C unpickler grows its memo to the
    largest index a PUT names, so one LONG_BINPUT of 4e9 in a 2 KB file would make it allocate
    (and clear) tens of GB; a pickler numbers the memo from 0, one entry per PUT."""
    for count, (op, arg, pos) in enumerate(pickletools.genops(data)):
        if op.name in ("PUT", "BINPUT", "LONG_BINPUT") and arg > count:
            raise CheckpointError("malformed data.pkl: memo index %d at byte %d is beyond the %d "
                                  "opcodes before it" % (arg, pos, count))


class _RestrictedUnpickler(pickle.Unpickler):
    def __init__(self, file, archive):
        super().__init__(file, encoding="utf-8")
        self._data = file.getvalue()  # for _check_memo_indices (file is an io.BytesIO)
        self.archive = archive
        self.storages = {}
        self.placeholders = {}

    def load(self):
        _check_memo_indices(self._data)
        return super().load()

    def find_class(self, module, name):
        if not isinstance(module, str) or not isinstance(name, str):
            raise CheckpointError("malformed checkpoint: non-string global name")
        module = _MODULE_ALIASES.get(module, module)
        found = _ALLOWED.get((module, name))
        if found is not None:
            return found
        display = _display_global(module, name)
        if _is_dangerous(module, name):
            raise CheckpointError("refusing to load checkpoint: it references %s" % display)
        cls = self.placeholders.get(display)
        if cls is None:
            cls = type("Unresolved", (_Unresolved,), {"global_name": display})
            self.placeholders[display] = cls
        return cls

    def persistent_load(self, pid):
        if not isinstance(pid, tuple) or len(pid) != 5 or pid[0] not in ("storage", b"storage"):
            raise CheckpointError("malformed checkpoint: unsupported persistent id %s"
                                  % _one_line(repr(pid))[:80])
        _, storage_type, key, location, numel = pid
        unresolved = _unresolved_instance(storage_type)
        if unresolved is not None:  # e.g. torch.QInt8Storage: fine in a skipped entry only
            return unresolved
        if not isinstance(storage_type, _StorageType):
            raise CheckpointError("malformed checkpoint: storage type %s"
                                  % _one_line(repr(storage_type))[:80])
        if isinstance(key, bytes):
            key = key.decode("ascii", "replace")
        if isinstance(location, bytes):
            location = location.decode("ascii", "replace")
        if not isinstance(key, str) or not key or "/" in key or key in (".", ".."):
            raise CheckpointError("malformed checkpoint: storage key %r" % (key,))
        if not _is_int(numel) or numel < 0:
            raise CheckpointError("malformed checkpoint: storage %r has %r elements" % (key, numel))
        storage = self.storages.get(key)
        if storage is None:
            storage = _Storage(self.archive, key, storage_type.dtype, int(numel), str(location))
            self.storages[key] = storage
        elif storage.dtype != storage_type.dtype or storage.numel != numel:
            raise CheckpointError("malformed checkpoint: storage %r is declared both as %d %s and "
                                  "as %d %s elements" % (key, storage.numel, storage.dtype, numel,
                                                         storage_type.dtype))
        return storage


# ---------------------------------------------------------------------------------------------
# The archive


class _Archive:
    def __init__(self, path, zf, prefix, byteorder, version):
        self.path = path
        self.zf = zf
        self.prefix = prefix
        self.byteorder = byteorder
        self.version = version

    def record_name(self, key):
        return "%sdata/%s" % (self.prefix, key)

    def info(self, key):
        try:
            return self.zf.getinfo(self.record_name(key))
        except KeyError:
            return None

    def read(self, key, start, length, label):
        """Bytes [start, start + length) of a storage record. Records stored uncompressed (as
        torch writes them) are read in place with pread, so a view into a large storage costs
        only its own bytes; a whole record is checked against its CRC-32."""
        info = self.info(key)
        name = self.record_name(key)
        if self.zf.fp is None:
            raise CheckpointError("%s: checkpoint %s was closed" % (label, self.path))
        whole = start == 0 and length == info.file_size
        try:
            if info.compress_type == zipfile.ZIP_STORED and not info.flag_bits & 1:
                data = self._read_stored(info, start, length)
                if whole and zlib.crc32(data) != info.CRC:
                    raise zipfile.BadZipFile("Bad CRC-32 for file %r" % name)
            else:
                with self.zf.open(info) as f:
                    if whole:
                        data = f.read()  # zipfile verifies the CRC
                    else:
                        f.seek(start)
                        data = f.read(length)
        except _ZIP_ERRORS as e:
            raise CheckpointError("%s: cannot read storage record %r of %s: %s"
                                  % (label, name, self.path, _one_line(e))) from None
        if len(data) != length:
            raise CheckpointError("%s: storage record %r of %s ended after %d of %d bytes"
                                  % (label, name, self.path, len(data), length))
        return data

    def _read_stored(self, info, start, length):
        fd = self.zf.fp.fileno()
        header = os.pread(fd, 30, info.header_offset)
        if len(header) != 30 or header[:4] != b"PK\x03\x04":
            raise zipfile.BadZipFile("bad local file header")
        name_len = int.from_bytes(header[26:28], "little")
        extra_len = int.from_bytes(header[28:30], "little")
        data_start = info.header_offset + 30 + name_len + extra_len
        if data_start + info.file_size > os.fstat(fd).st_size:
            raise zipfile.BadZipFile("record extends past the end of the file")
        buffer = np.empty(length, dtype=np.uint8)  # writable, so .numpy() may keep it
        view = memoryview(buffer)
        done = 0
        while done < length:
            n = os.preadv(fd, [view[done:done + (1 << 30)]], data_start + start + done)
            if n <= 0:
                break
            done += n
        return buffer[:done]

    def close(self):
        self.zf.close()


def _open_archive(path):
    path = os.fspath(path)
    try:
        with open(path, "rb") as f:
            head = f.read(len(_LEGACY_MAGIC))
    except OSError as e:
        raise CheckpointError("cannot open checkpoint %s: %s" % (path, _one_line(e.strerror or e)))
    try:
        zf = zipfile.ZipFile(path, "r")
    except _ZIP_ERRORS as e:
        if head.startswith(_LEGACY_MAGIC):
            raise CheckpointError(
                "%s uses the legacy (pre-1.6, non-zip) torch.save format, which is not supported; "
                "re-save it with torch >= 1.6: torch.save(torch.load(f), f2)" % path) from None
        if head.startswith(b"PK"):
            raise CheckpointError("%s is a truncated or corrupt zip archive (%s)"
                                  % (path, _one_line(e))) from None
        try:
            is_tar = tarfile.is_tarfile(path)
        except OSError:
            is_tar = False
        if is_tar:
            raise CheckpointError("%s uses the legacy tar torch.save format, which is not "
                                  "supported; re-save it with torch >= 1.6" % path) from None
        raise CheckpointError("%s is not a PyTorch zip checkpoint (%s)"
                              % (path, _one_line(e))) from None
    try:
        names = zf.namelist()
        pickles = [n for n in names if n.count("/") == 1 and n.endswith("/data.pkl")]
        if any(n.count("/") == 1 and n.endswith("/constants.pkl") for n in names):
            raise CheckpointError("%s is a TorchScript archive (torch.jit.save), not a "
                                  "torch.save checkpoint" % path)
        if len(pickles) != 1:
            raise CheckpointError("%s is a zip archive but not a torch.save checkpoint (%s "
                                  "<archive>/data.pkl records)" % (path, len(pickles) or "no"))
        prefix = pickles[0][: -len("data.pkl")]
        byteorder = "little"
        if prefix + "byteorder" in names:
            byteorder = zf.read(prefix + "byteorder").decode("ascii", "replace").strip()
            if byteorder not in ("little", "big"):
                raise CheckpointError("%s: unknown byteorder record %r" % (path, byteorder[:20]))
        version = None
        if prefix + "version" in names:
            version = zf.read(prefix + "version").decode("ascii", "replace").strip()
        return _Archive(path, zf, prefix, byteorder, version)
    except CheckpointError:
        zf.close()
        raise
    except _ZIP_ERRORS as e:
        zf.close()
        raise CheckpointError("%s is a corrupt zip archive (%s)" % (path, _one_line(e))) from None


def _unresolved_in(obj):
    """Names of the placeholder globals found anywhere inside obj."""
    found = set()
    stack = [obj]
    seen = set()
    while stack:
        x = stack.pop()
        if isinstance(x, _Unresolved) or (isinstance(x, type) and issubclass(x, _Unresolved)):
            found.add(x.global_name)
            continue
        if id(x) in seen:
            continue
        if isinstance(x, dict):
            seen.add(id(x))
            stack.extend(x.keys())
            stack.extend(x.values())
        elif isinstance(x, (list, tuple, set, frozenset)):
            seen.add(id(x))
            stack.extend(x)
    return found


class Checkpoint:
    """An opened checkpoint.

    state_dict  dict[str, TensorRef], in the checkpoint's order
    key         the top-level entry the state_dict came from ("model", "state_dict", ...), or
                None for a bare state_dict
    extra       the other top-level entries of a wrapper (optimizer state, step counters, ...),
                with any tensors in them as TensorRef
    skipped     top-level entries left out of `extra` -> sorted names of the unknown globals
                they need (never imported, never called)
    version, byteorder   of the archive
    """

    def __init__(self, archive, state_dict, key, extra, skipped):
        self._archive = archive
        self.path = archive.path
        self.state_dict = state_dict
        self.key = key
        self.extra = extra
        self.skipped = skipped
        self.version = archive.version
        self.byteorder = archive.byteorder

    def close(self):
        """Closes the file; TensorRef.numpy() fails afterwards."""
        self._archive.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


_WRAPPER_KEYS = ("model", "state_dict")


def open_checkpoint(path, key=None):
    """Opens a torch.save zip checkpoint and returns a Checkpoint (no tensor data read yet).

    key: the top-level entry holding the state_dict. None picks "model" (the official SPAR
    training wrapper) or "state_dict" (e.g. Lightning checkpoints) when the file holds a dict
    with such an entry that is itself a dict, and otherwise takes the whole file as a bare
    state_dict. Every state_dict entry must be a tensor with a string key, and its storage
    record must hold every element of the view; anything else raises CheckpointError.
    """
    archive = _open_archive(path)
    try:
        return _load(archive, key)
    except BaseException:
        archive.close()
        raise


def load_state_dict(path, key=None):
    """The state_dict of a checkpoint: dict[str, TensorRef] (see open_checkpoint)."""
    return open_checkpoint(path, key).state_dict


def _load(archive, key):
    path = archive.path
    try:
        data = archive.zf.read(archive.prefix + "data.pkl")
    except _ZIP_ERRORS as e:
        raise CheckpointError("%s: cannot read %sdata.pkl: %s"
                              % (path, archive.prefix, _one_line(e))) from None
    unpickler = _RestrictedUnpickler(io.BytesIO(data), archive)
    try:
        top = unpickler.load()
    except CheckpointError as e:
        if path in str(e):
            raise
        raise CheckpointError("%s: %s" % (path, e)) from None
    except RecursionError:
        raise CheckpointError("%s: data.pkl is nested too deeply" % path) from None
    except Exception as e:  # pickle.UnpicklingError, EOFError, TypeError, ... from bad data
        raise CheckpointError("%s: malformed data.pkl (%s: %s)"
                              % (path, type(e).__name__, _one_line(e)[:200])) from None

    def refuse_unresolved(obj, where):
        names = _unresolved_in(obj)
        if names:
            raise CheckpointError("refusing to load checkpoint %s: %s references %s, which is "
                                  "not allowed" % (path, where, ", ".join(sorted(names))))

    extra, skipped = {}, {}
    if key is None:
        if isinstance(top, dict):
            for candidate in _WRAPPER_KEYS:
                if isinstance(top.get(candidate), dict):
                    key = candidate
                    break
    if key is not None:
        if not isinstance(top, dict) or key not in top:
            raise CheckpointError("%s has no top-level entry %r" % (path, key))
        state = top[key]
        refuse_unresolved(state, "its %r entry" % key)
        for k, v in top.items():
            if k == key:
                continue
            names = _unresolved_in([k, v])
            if names:
                skipped[k] = sorted(names)
            else:
                extra[k] = v
    else:
        state = top
        refuse_unresolved(state, "its state_dict")
    if not isinstance(state, dict):
        raise CheckpointError("%s: the state_dict is a %s, not a dict"
                              % (path, type(state).__name__))
    result = {}
    for name, value in state.items():
        if not isinstance(name, str):
            raise CheckpointError("%s: state_dict key %r is not a string" % (path, name))
        if not isinstance(value, TensorRef):
            raise CheckpointError("%s: state_dict entry %r is a %s, not a tensor"
                                  % (path, name, type(value).__name__))
        value._check_extent(name)
        if value.name is None:
            value.name = name
        result[name] = value
    for name, value in result.items():  # after the extents, so that those errors come first
        value._check_record_size(name)
    return Checkpoint(archive, result, key, extra, skipped)


# ---------------------------------------------------------------------------------------------
# TorchScript archives (torch.jit.save), e.g. OpenAI's CLIP ViT-B-32.pt: only the tensors


class _ScriptObject(_Unresolved):
    """A TorchScript module (``__torch__.*`` class): keeps the attribute dict that pickle's
    BUILD passes (parameters, buffers and submodules by attribute name); nothing is called."""

    def __setstate__(self, state):
        self.script_state = state if isinstance(state, dict) else None


class _ScriptUnpickler(_RestrictedUnpickler):
    def find_class(self, module, name):
        if isinstance(module, str) and isinstance(name, str) and \
                (module == "__torch__" or module.startswith("__torch__.")):
            display = "%s.%s" % (module, name)
            cls = self.placeholders.get(display)
            if cls is None:
                cls = type("ScriptObject", (_ScriptObject,), {"global_name": display})
                self.placeholders[display] = cls
            return cls
        return super().find_class(module, name)


def _script_tensors(root):
    """Tensor attributes of a TorchScript module tree, named like its state_dict."""
    out = {}
    seen = set()
    stack = [("", root)]
    while stack:
        prefix, obj = stack.pop()
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        state = getattr(obj, "script_state", None)
        if not isinstance(state, dict):
            continue
        items = [(k, v) for k, v in state.items() if isinstance(k, str)]
        for k, v in reversed(items):
            if isinstance(v, TensorRef):
                out[prefix + k] = v
            elif isinstance(v, _ScriptObject):
                stack.append((prefix + k + ".", v))
    return dict(sorted(out.items(), key=lambda kv: _natural_key(kv[0])))


def _natural_key(name):
    return [(0, int(p), "") if p.isdigit() else (1, 0, p) for p in name.split(".")]


def open_torchscript(path):
    """Opens a TorchScript archive (torch.jit.save) and returns a Checkpoint whose state_dict
    holds the tensor attributes of its module tree (the names of the module's state_dict).
    Like open_checkpoint: no code runs, nothing is imported, tensors are read on demand."""
    path = os.fspath(path)
    try:
        zf = zipfile.ZipFile(path, "r")
    except _ZIP_ERRORS as e:
        raise CheckpointError("%s is not a TorchScript archive (%s)" % (path, _one_line(e))) from None
    try:
        names = zf.namelist()
        pickles = [n for n in names if n.count("/") == 1 and n.endswith("/data.pkl")]
        if len(pickles) != 1 or not any(n.endswith("/constants.pkl") for n in names):
            raise CheckpointError("%s is not a TorchScript archive" % path)
        prefix = pickles[0][: -len("data.pkl")]
        byteorder = "little"
        if prefix + "byteorder" in names:
            byteorder = zf.read(prefix + "byteorder").decode("ascii", "replace").strip()
            if byteorder not in ("little", "big"):
                raise CheckpointError("%s: unknown byteorder record %r" % (path, byteorder[:20]))
        version = zf.read(prefix + "version").decode("ascii", "replace").strip() \
            if prefix + "version" in names else None
        archive = _Archive(path, zf, prefix, byteorder, version)
        try:
            data = zf.read(prefix + "data.pkl")
        except _ZIP_ERRORS as e:
            raise CheckpointError("%s: cannot read %sdata.pkl: %s"
                                  % (path, prefix, _one_line(e))) from None
        try:
            root = _ScriptUnpickler(io.BytesIO(data), archive).load()
        except CheckpointError:
            raise
        except RecursionError:
            raise CheckpointError("%s: data.pkl is nested too deeply" % path) from None
        except Exception as e:
            raise CheckpointError("%s: malformed data.pkl (%s: %s)"
                                  % (path, type(e).__name__, _one_line(e)[:200])) from None
        if not isinstance(root, _ScriptObject):
            raise CheckpointError("%s: the TorchScript archive does not hold a module" % path)
        result = _script_tensors(root)
        for name, value in result.items():
            value._check_extent(name)
            if value.name is None:
                value.name = name
        for name, value in result.items():
            value._check_record_size(name)
        return Checkpoint(archive, result, None, {}, {})
    except CheckpointError:
        zf.close()
        raise
    except _ZIP_ERRORS as e:  # a damaged member (byteorder, version), as _open_archive
        zf.close()
        raise CheckpointError("%s is a corrupt zip archive (%s)" % (path, _one_line(e))) from None
    except BaseException:
        zf.close()
        raise


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if not argv or len(argv) > 2 or argv[0] in ("-h", "--help"):
        print("usage: python3 -m spar_convert.torch_checkpoint CHECKPOINT [KEY]", file=sys.stderr)
        return 2
    try:
        with open_checkpoint(argv[0], argv[1] if len(argv) > 1 else None) as ckpt:
            for name, t in ckpt.state_dict.items():
                print("%-60s %-8s %s" % (name, t.dtype, list(t.shape)))
            total = sum(t.numel for t in ckpt.state_dict.values())
            print("%d tensors, %d elements; from %s; other entries: %s; skipped: %s" % (
                len(ckpt.state_dict), total, repr(ckpt.key) if ckpt.key else "bare state_dict",
                sorted(map(str, ckpt.extra)) or "none",
                ", ".join("%s (%s)" % (k, ", ".join(v)) for k, v in ckpt.skipped.items())
                or "none"))
    except CheckpointError as e:
        print("error: %s" % e, file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
