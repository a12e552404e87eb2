#!/usr/bin/env python3
"""The CPU peer of spar-bench's cases: the same op, shape and float32 data size, timed with
numpy (GEMMs and attention: OpenBLAS's sgemm, softmax in numpy) and PyTorch eager
(convolutions: oneDNN; row ops), on all of this machine's cores. spar-bench --peer runs it
after its own cases, in the same run, with OPENBLAS_CORETYPE and OPENBLAS_L2_SIZE removed from
this process's environment (they hold OpenBLAS to narrower kernels than the CPU has;
docs/benchmarks.md).

    bench_peer.py IN.json OUT.json

IN: {"repeat": R, "cases": [spec or null, ...]}; a spec is spar-bench's description of a case
(tools/spar_bench/bench_cases.cpp, BenchCase::peer). OUT: {"peer": "what ran", "ms": [median or null,
...]}, the median of R timed runs after warm-up runs, in milliseconds.
"""
import json
import os
import sys
import time

import numpy as np


def _torch():
    import torch  # imported only where a case needs it (about a second)
    torch.set_num_threads(os.cpu_count() or 1)
    return torch


def gemm(s, rng):
    x = rng.standard_normal((s["m"], s["k"]), dtype=np.float32)
    w = rng.standard_normal((s["n"], s["k"]), dtype=np.float32)
    wt = w.T  # y = x w^T, as the engine's linear layers compute it
    out = np.empty((s["m"], s["n"]), dtype=np.float32)
    return lambda: np.matmul(x, wt, out=out)


def attention(s, rng):
    # numpy rather than PyTorch: Debian's torch 1.13 batches bmm without BLAS (8 GFLOPS here)
    b, n, h, d = s["batch"], s["tokens"], s["heads"], s["dim"]
    q, k, v = (rng.standard_normal((b * h, n, d), dtype=np.float32) for _ in range(3))
    kt = k.transpose(0, 2, 1)
    scale = np.float32(d ** -0.5)

    def run():
        p = np.matmul(q, kt)
        p *= scale
        p -= p.max(axis=-1, keepdims=True)
        np.exp(p, out=p)
        p /= p.sum(axis=-1, keepdims=True)
        return np.matmul(p, v)
    return run


def conv(s, rng, transposed):
    torch = _torch()
    f = torch.nn.functional
    x = torch.from_numpy(rng.standard_normal((s["n"], s["cin"], s["h"], s["w"]), dtype=np.float32))
    shape = (s["cin"], s["cout"], s["k"], s["k"]) if transposed else (s["cout"], s["cin"], s["k"], s["k"])
    w = torch.from_numpy(rng.standard_normal(shape, dtype=np.float32))
    b = torch.from_numpy(rng.standard_normal((s["cout"],), dtype=np.float32)) if s.get("bias") else None

    def run():
        with torch.no_grad():
            y = (f.conv_transpose2d(x, w, b, stride=s["k"]) if transposed
                 else f.conv2d(x, w, b, padding=s.get("pad", 0)))
            return f.gelu(y) if s.get("gelu") else y
    return run


def row_op(s, rng):
    torch = _torch()
    x = torch.from_numpy(rng.standard_normal((s["rows"], s["cols"]), dtype=np.float32))
    w, b = torch.ones(s["cols"]), torch.zeros(s["cols"])
    if s["op"] == "layernorm":
        return lambda: torch.nn.functional.layer_norm(x, (s["cols"],), w, b)
    return lambda: torch.softmax(x, dim=-1)


def make(spec, rng):
    op = spec["op"]
    if op == "gemm":
        return gemm(spec, rng)
    if op == "attention":
        return attention(spec, rng)
    if op in ("conv2d", "conv_transpose2d"):
        return conv(spec, rng, op == "conv_transpose2d")
    if op in ("layernorm", "softmax"):
        return row_op(spec, rng)
    raise SystemExit(f"bench_peer.py: unknown op {op!r}")


def blas_name():
    """The BLAS this process loaded (Debian's numpy takes whichever libblas.so.3 is selected) and,
    for OpenBLAS, the kernels it chose for this CPU: what OPENBLAS_CORETYPE would have forced."""
    import ctypes
    with open("/proc/self/maps") as maps:
        paths = sorted({line.split()[-1] for line in maps if "openblas" in line and ".so" in line})
    for path in paths:
        lib = ctypes.CDLL(path)
        if hasattr(lib, "openblas_get_corename"):
            lib.openblas_get_corename.restype = ctypes.c_char_p
            return f"OpenBLAS, {lib.openblas_get_corename().decode()} kernels"
    return "its BLAS"


def median_ms(run, repeat):
    # Warm-up: buffers touched, thread pools started, and the allocator settled (PyTorch's first
    # 5 layernorms of 1280x768 take 7-9 ms, the next 0.3: glibc maps each fresh output anew until
    # its mmap threshold has grown past the output's size).
    start, runs = time.perf_counter(), 0
    while runs < 2 or (runs < 20 and time.perf_counter() - start < 0.25):
        run()
        runs += 1
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        run()
        times.append((time.perf_counter() - t) * 1e3)
    return sorted(times)[len(times) // 2]


def main():
    if len(sys.argv) != 3:
        raise SystemExit("usage: bench_peer.py IN.json OUT.json")
    with open(sys.argv[1]) as f:
        job = json.load(f)
    rng = np.random.default_rng(0)
    ms = [median_ms(make(spec, rng), int(job["repeat"])) if spec else None for spec in job["cases"]]
    used = {spec["op"] for spec in job["cases"] if spec}
    peer = f"numpy {np.__version__} ({blas_name()})"
    if used - {"gemm", "attention"}:
        import torch
        peer += f"; PyTorch {torch.__version__} eager"
    peer += f", float32, {os.cpu_count()} threads"
    with open(sys.argv[2], "w") as f:
        json.dump({"peer": peer, "ms": ms}, f)


if __name__ == "__main__":
    main()
