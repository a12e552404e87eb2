"""Block quantization of weight matrices (FORMAT.md, "Quantized matrices"): ``q8`` and ``q4``.

A matrix ``[N, K]`` is cut into blocks of ``BLOCK`` = 32 consecutive values along K (the input
dimension, contiguous in PyTorch's ``[out, in]`` layout, the one every GEMM of the engine walks);
K is a multiple of 32 (the converter quantizes no other matrix). Each block has one float32 scale
``s = max|w| / Q`` (Q = 127 for q8, 7 for q4), and codes ``c = round(w / s)`` in [-Q, Q]:

* q8: one int8 per value, stored I8 ``[N, K]``;
* q4: one nibble per value, ``c + 8`` in [1, 15], two per byte (even k in the low nibble),
  stored U8 ``[N, K / 2]``;
* the scales F32 ``[N, K / 32]`` in the tensor ``<name>.qscale``.

Read back as little-endian 32-bit words (4 int8 or 8 nibbles each), so a device needs no 8- or
16-bit storage feature; a value is ``c * s``. Symmetric codes keep 0 exact (padding, pruned
weights) and need no second number per block. numpy only (no torch)."""
import numpy as np

BLOCK = 32
SCALE_SUFFIX = ".qscale"  # the scales of matrix NAME are the tensor NAME.qscale
LEVELS = {"q8": 127, "q4": 7}
BITS = {"q8": 8, "q4": 4}


def quantize(a, kind: str):
    """(codes, scales) of the 2-D float array ``a`` (see the module's docstring)."""
    if kind not in LEVELS:
        raise ValueError("unknown quantization %r" % kind)
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2:
        raise ValueError("only 2-D matrices are quantized, got shape %s" % list(a.shape))
    n, k = a.shape
    if k % BLOCK:
        raise ValueError("rows of %d values are not whole blocks of %d" % (k, BLOCK))
    blocks = a.reshape(n, k // BLOCK, BLOCK)
    q = LEVELS[kind]
    # the scale is rounded to float32 first: the codes are chosen for the scale the device uses
    scales = (np.max(np.abs(blocks), axis=2) / q).astype(np.float32)
    s = scales.astype(np.float64)[:, :, None]
    safe = np.where(s > 0, s, 1.0)
    codes = np.clip(np.rint(blocks / safe), -q, q).astype(np.int8).reshape(n, k)
    if kind == "q8":
        return codes, scales
    nib = (codes.astype(np.int16) + 8).astype(np.uint8)
    return (nib[:, 0::2] | (nib[:, 1::2] << 4)).astype(np.uint8), scales


def dequantize(codes, scales, kind: str):
    """The float64 values a device computes with: ``[N, K]``."""
    codes = np.asarray(codes)
    n = codes.shape[0]
    if kind == "q8":
        c = codes.astype(np.float64)
    else:
        c = np.empty((n, codes.shape[1] * 2), dtype=np.float64)
        c[:, 0::2] = (codes & 0xF).astype(np.float64) - 8
        c[:, 1::2] = (codes >> 4).astype(np.float64) - 8
    s = np.repeat(np.asarray(scales, dtype=np.float64), BLOCK, axis=1)
    return c * s
