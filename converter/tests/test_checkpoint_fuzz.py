#!/usr/bin/python3
"""Seeded mutation fuzzing of spar_convert.torch_checkpoint (open_checkpoint, open_torchscript,
TensorRef.numpy): mutants of the committed seeds (tests/fuzz/corpus/checkpoint/, written by
tests/fuzz/make_corpus.py) must open and read, or fail with CheckpointError; any other
exception, a run over 10 s, or any sign of code from the file running (a sentinel global called,
os.system / subprocess used, a module imported) is a finding. Mutations, equally likely by family:
raw bytes of the file (bit flips, bytes, inserts, deletes, truncation, splices), zip members
(edit, drop, duplicate, rename, recompress, add), and data.pkl opcodes (integer and string
arguments, globals swapped for dangerous / unknown / allowed ones or the sentinel, ops deleted,
duplicated, inserted, sentinel calls injected), the archive rewritten with valid CRCs.

Deterministic for a seed. Bounded in CI (CTest py_converter: 20000 mutants, about
6 s); longer:
    SPAR_FUZZ_EXECS=100000 SPAR_FUZZ_SEED=1 /usr/bin/python3 -m pytest -q -s converter/tests/test_checkpoint_fuzz.py
A finding is saved to $SPAR_FUZZ_FINDINGS (default: <tmp>/spar_checkpoint_fuzz/) and named in
the one-line failure; replay it with /usr/bin/python3 -m spar_convert.torch_checkpoint FILE.
"""

import io
import os
import pickle
import pickletools
import random
import signal
import subprocess
import sys
import tempfile
import time
import types
import warnings
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

from spar_convert.torch_checkpoint import (
    CheckpointError, TensorRef, open_checkpoint, open_torchscript)

CORPUS = ROOT / "tests" / "fuzz" / "corpus" / "checkpoint"
EXECS = int(os.environ.get("SPAR_FUZZ_EXECS", "20000"))
SEED = int(os.environ.get("SPAR_FUZZ_SEED", "1"))
HANG_SECONDS = 10
SENTINEL = "spar_fuzz_sentinel"


class Hang(BaseException):
    """Raised by the alarm; a BaseException, so the reader's `except Exception` cannot hide it."""


# ---------------------------------------------------------------------------------------------
# Mutations

INTERESTING_INTS = [0, 1, -1, 2, 3, 4, 7, 8, 255, 256, 2**31 - 1, 2**31, 2**32, 2**62, 2**63 - 1,
                    2**63, 2**64, -2**63, 10**30]
INTERESTING_STRINGS = ["", "0", "1", "..", ".", "a/b", "/", "cpu", "cuda:0", "model", "state_dict",
                       "\x00", "data.pkl", "x" * 300]
GLOBALS = [(SENTINEL, "fire"), ("os", "system"), ("posix", "system"), ("builtins", "eval"),
           ("builtins", "exec"), ("__builtin__", "getattr"), ("subprocess", "Popen"),
           ("torch", "load"), ("torch.jit", "load"), ("numpy", "load"), ("collections", "Counter"),
           ("argparse", "Namespace"), ("torch", "FloatStorage"), ("torch", "HalfStorage"),
           ("torch", "BFloat16Storage"), ("torch", "BoolStorage"), ("torch", "QInt8Storage"),
           ("torch._utils", "_rebuild_tensor_v2"), ("torch._utils", "_rebuild_parameter"),
           ("torch._tensor", "_rebuild_from_type_v2"), ("collections", "OrderedDict"),
           ("builtins", "set"), ("_codecs", "encode"), ("torch", "Size")]
# Opcodes worth inserting alone: they build, call, fetch from the memo or end the pickle.
LONE_OPS = [b"R", b"b", b"u", b"s", b"a", b"e", b"}", b"]", b")", b"(", b"t", b"N", b"\x88", b"0",
            b".", b"Q", b"2", b"\x85", b"\x86", b"\x87", b"\x94", b"q\x00", b"h\x00", b"h\xff",
            b"j\xff\xff\xff\x7f", b"\x81", b"\x93"]
# GLOBAL, empty args, REDUCE, POP: a call of the sentinel, run by any ordinary unpickler.
SENTINEL_CALL = ("c%s\nfire\n)R0" % SENTINEL).encode()


def encode_int(value):
    if 0 <= value < 256:
        return b"K" + bytes([value])
    if -2**31 <= value < 2**31:
        return b"J" + value.to_bytes(4, "little", signed=True)
    n = (value.bit_length() + 8) // 8
    return b"\x8a" + bytes([n]) + value.to_bytes(n, "little", signed=True)


def encode_str(text):
    data = text.encode("utf-8", "surrogatepass")
    return b"X" + len(data).to_bytes(4, "little") + data


def parse_pickle(data):
    """The opcodes of a pickle [(op, arg, pos)] and the indices of its integer, string and
    GLOBAL opcodes (raises where pickletools cannot parse it)."""
    ops = [(op, arg, pos) for op, arg, pos in pickletools.genops(data)]
    ints = [k for k, (o, a, _) in enumerate(ops) if isinstance(a, int) and not isinstance(a, bool)
            and o.name in ("BININT", "BININT1", "BININT2", "LONG1", "INT", "LONG")]
    strs = [k for k, (o, a, _) in enumerate(ops) if isinstance(a, str)
            and o.name in ("BINUNICODE", "SHORT_BINUNICODE", "UNICODE", "BINSTRING",
                           "SHORT_BINSTRING")]
    globs = [k for k, (o, _, _) in enumerate(ops) if o.name == "GLOBAL"]
    return ops, ints, strs, globs


class Mutator:
    def __init__(self, seed, seeds):
        self.rng = random.Random(seed)
        self.seeds = seeds  # list of (file bytes, [(name, data, compress_type)])
        # The seeds' own pickles, parsed once: every pickle mutant starts from one of them (the
        # mutants are the same as when each was parsed anew).
        self.parsed = {d: parse_pickle(d) for _, members in seeds for n, d, _ in members
                       if n.endswith(".pkl")}

    def raw(self, b, times=None):
        """1-4 blind edits of a byte string."""
        r = self.rng
        b = bytearray(b)
        for _ in range(times or r.randint(1, 4)):
            if not b:
                b.append(0)
            pos = r.randrange(len(b))
            kind = r.randrange(7)
            if kind == 0:
                b[pos] ^= 1 << r.randrange(8)
            elif kind == 1:
                b[pos] = r.choice([0, 1, 0x7f, 0x80, 0xff, r.randrange(256)])
            elif kind == 2:
                b[pos:pos] = bytes(r.randrange(256) for _ in range(r.randint(1, 8)))
            elif kind == 3:
                del b[pos:pos + r.randint(1, 64)]
            elif kind == 4:
                start = r.randrange(len(b))
                b[pos:pos] = b[start:start + r.randint(1, 128)]
            elif kind == 5:
                del b[r.randrange(len(b) + 1):]
            else:
                other = r.choice(self.seeds)[0]
                start = r.randrange(len(other))
                piece = other[start:start + r.randint(1, 256)]
                b[pos:pos + len(piece)] = piece
        return bytes(b)

    def pickle_ops(self, data):
        """1-3 edits of a pickle at opcode boundaries (blind edits once it no longer parses)."""
        r = self.rng
        for _ in range(r.randint(1, 3)):
            try:
                ops, ints, strs, globs = self.parsed.get(data) or parse_pickle(data)
            except Exception:
                return self.raw(data, 1)
            i = r.randrange(len(ops))
            op, arg, pos = ops[i]
            end = ops[i + 1][2] if i + 1 < len(ops) else len(data)
            kind = r.randrange(6)
            pick = None
            if kind == 0 and ints:
                pick = r.choice(ints), encode_int(r.choice(INTERESTING_INTS + [r.randint(-9, 9)]))
            elif kind == 1 and strs:
                pick = r.choice(strs), encode_str(r.choice(INTERESTING_STRINGS))
            elif kind == 2 and globs:
                module, name = r.choice(GLOBALS)
                pick = r.choice(globs), ("c%s\n%s\n" % (module, name)).encode()
            if pick is not None:
                k, new = pick
                a, b = ops[k][2], ops[k + 1][2] if k + 1 < len(ops) else len(data)
                data = data[:a] + new + data[b:]
            elif kind == 3:  # delete or duplicate an op
                data = data[:pos] + (data[pos:end] * 2 if r.randrange(2) else b"") + data[end:]
            elif kind == 4:
                data = data[:pos] + r.choice(LONE_OPS) + data[pos:]
            else:
                data = data[:pos] + SENTINEL_CALL + data[pos:]
        return data

    def members(self, members):
        """One edit of the archive's member list (names, data, compression)."""
        r = self.rng
        members = list(members)
        i = r.randrange(len(members))
        name, data, compression = members[i]
        kind = r.randrange(7)
        if kind == 0:
            members[i] = (name, self.raw(data), compression)
        elif kind == 1:
            del members[i]
        elif kind == 2:
            members.insert(r.randrange(len(members) + 1), members[i])
        elif kind == 3:
            parts = name.split("/")
            parts[r.randrange(len(parts))] = r.choice(["data", "0", "1", "archive", "x", "", "data.pkl",
                                                       "constants.pkl", "byteorder", "version"])
            members[i] = ("/".join(parts), data, compression)
        elif kind == 4:
            other = zipfile.ZIP_STORED if compression != zipfile.ZIP_STORED else zipfile.ZIP_DEFLATED
            members[i] = (name, data, other)
        elif kind == 5:
            members[i] = (name, data[:r.randrange(len(data) + 1)], compression)
        else:
            prefix = name.split("/")[0]
            extra = r.choice([("other/data.pkl", pickle.dumps({})), (prefix + "/byteorder", b"big"),
                              (prefix + "/byteorder", b"middle"), (prefix + "/constants.pkl", b"\x80\x02)."),
                              (prefix + "/data/99", bytes(8))])
            members.append(extra + (zipfile.ZIP_STORED,))
        return members

    def mutant(self):
        r = self.rng
        file_bytes, members = r.choice(self.seeds)
        family = r.randrange(3)
        if family == 0:
            return self.raw(file_bytes)
        if family == 1:
            for _ in range(r.randint(1, 2)):
                if members:
                    members = self.members(members)
        else:
            members = [(n, self.pickle_ops(d) if n.endswith(".pkl") else d, c) for n, d, c in members]
        return zip_bytes(members)


def zip_bytes(members):
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as z, warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # a duplicate name is one of the mutations
        for name, data, compression in members:
            info = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))
            info.compress_type = compression
            with z.open(info, "w", force_zip64=False) as f:  # duplicate names allowed here
                f.write(data)
    return out.getvalue()


def load_seeds():
    seeds = []
    for path in sorted(CORPUS.glob("*.pt")):
        data = path.read_bytes()
        with zipfile.ZipFile(io.BytesIO(data)) as z:
            members = [(i.filename, z.read(i), i.compress_type) for i in z.infolist()]
        seeds.append((data, members))
    assert seeds, "no seeds in %s (tests/fuzz/make_corpus.py writes them)" % CORPUS
    return seeds


# ---------------------------------------------------------------------------------------------
# Running the reader


def read_everything(path):
    """What the converter does with a checkpoint: open it, read every tensor (of the state_dict
    and of the other entries). Returns the number of tensors read."""
    read = 0
    for opener in (open_checkpoint, open_torchscript):
        try:
            ckpt = opener(path)
        except CheckpointError:
            continue
        with ckpt:
            stack = [ckpt.state_dict, ckpt.extra]
            while stack:
                x = stack.pop()
                if isinstance(x, TensorRef):
                    try:
                        x.numpy()
                        read += 1
                    except CheckpointError:
                        pass
                elif isinstance(x, dict):
                    stack.extend(x.values())
                elif isinstance(x, (list, tuple)):
                    stack.extend(x)
    return read


@pytest.fixture
def tripwires(monkeypatch):
    """Records any use of the sentinel module or of the usual ways to run a command."""
    calls = []

    def trip(what):
        def record(*args, **kwargs):
            calls.append(what)
        return record

    sentinel = types.ModuleType(SENTINEL)
    sentinel.fire = trip(SENTINEL + ".fire")
    monkeypatch.setitem(sys.modules, SENTINEL, sentinel)
    for module, name in ((os, "system"), (os, "popen"), (os, "execv"), (os, "execve"),
                         (subprocess, "Popen")):
        monkeypatch.setattr(module, name, trip("%s.%s" % (module.__name__, name)))
    return calls


def test_sentinel_call_fires_under_plain_pickle(tripwires):
    """The sentinel the fuzzing injects does run code under an ordinary unpickler (so its
    silence below means something)."""
    payload = pickle.dumps({"w": 1}, protocol=2)
    pickle.loads(payload[:-1] + SENTINEL_CALL + b".")
    assert tripwires == [SENTINEL + ".fire"]


def test_seeds_are_read(tmp_path, tripwires):
    for path in sorted(CORPUS.glob("*.pt")):
        assert read_everything(path) > 0, path
    assert not tripwires


# pickletools warns about the bad escapes of mutated UNICODE arguments; harmless.
@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_mutated_checkpoints_fail_only_with_checkpoint_error(tmp_path, tripwires, capsys):
    seeds = load_seeds()
    mutator = Mutator(SEED, seeds)
    findings = Path(os.environ.get("SPAR_FUZZ_FINDINGS",
                                   os.path.join(tempfile.gettempdir(), "spar_checkpoint_fuzz")))
    path = tmp_path / "input.pt"
    # Each mutant is written over the previous one in place, then the file cut to its length:
    # the reader, opening it by name, sees exactly the mutant. (Truncating to zero and writing
    # anew, as open(..., "wb") does, made ext4 flush the file at the next close: 0.13 ms a
    # mutant, a quarter of the run.)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)

    def on_alarm(signum, frame):
        raise Hang("over %d s" % HANG_SECONDS)

    previous = signal.signal(signal.SIGALRM, on_alarm)
    # Modules the stdlib loads on first use, whatever the file: tarfile.is_tarfile (the reader's
    # probe of a file that is not a zip) its decompressors, zipfile (member names) and pickle and
    # pickletools (string opcodes) their fixed codecs. Any other new module is a finding.
    import bz2, codecs, gzip, lzma  # noqa: E401, F401
    for codec in ("raw-unicode-escape", "unicode-escape", "latin-1", "ascii", "utf-8", "cp437"):
        codecs.lookup(codec)
    modules = set(sys.modules)
    start = time.monotonic()
    outcomes = {"read": 0, "refused": 0}
    try:
        for n in range(EXECS):
            data = mutator.mutant()
            os.pwrite(fd, data, 0)
            os.ftruncate(fd, len(data))
            problem = None
            signal.setitimer(signal.ITIMER_REAL, HANG_SECONDS)
            try:
                outcomes["read" if read_everything(path) else "refused"] += 1
            except Hang as e:
                problem = "hang (%s)" % e
            except Exception as e:  # anything but CheckpointError (caught inside)
                problem = "%s: %s" % (type(e).__name__, " ".join(str(e).split())[:200])
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
            imported = sorted(set(sys.modules) - modules)
            if problem is None and tripwires:
                problem = "code from the file ran: %s" % ", ".join(tripwires)
            if problem is None and imported:
                problem = "the reader imported %s" % ", ".join(imported)
            if problem:
                findings.mkdir(parents=True, exist_ok=True)
                saved = findings / ("finding-%d-%d.pt" % (SEED, n))
                saved.write_bytes(data)
                pytest.fail("checkpoint fuzz: %s on the input saved as %s (seed %d, execution %d)"
                            % (problem, saved, SEED, n), pytrace=False)
    finally:
        signal.signal(signal.SIGALRM, previous)
        os.close(fd)
    seconds = time.monotonic() - start
    with capsys.disabled():
        print("\ncheckpoint fuzz: %d executions (seed %d, %d seeds) in %.1f s, %.0f/s, 0 findings; "
              "%d read something, %d refused"
              % (EXECS, SEED, len(seeds), seconds, EXECS / max(seconds, 1e-9), outcomes["read"],
                 outcomes["refused"]))
