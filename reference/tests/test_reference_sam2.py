#!/usr/bin/python3
"""The SAM2.1 refinement reference (spar_reference.sam2) against independent float64 sums of the
formulas of the official code (as docs/sam2.md states them): the bicubic background position embedding
(A = -0.75, unclamped source, clamped taps), a windowed block whose zero-padded windows keep
their pad tokens as keys and values, a q-pooling transition block, the random-Fourier dense PE,
SPAR's uint8 truncation and its skip rule at both edges."""
import math

import numpy as np
import pytest
import torch

from spar_convert.sam2_config import Sam2Config
from spar_reference import sam2

torch.set_num_threads(1)
D = torch.float64


def cubic(x, a=-0.75):
    x = abs(x)
    if x <= 1:
        return (a + 2) * x ** 3 - (a + 3) * x ** 2 + 1
    if x < 2:
        return a * x ** 3 - 5 * a * x ** 2 + 8 * a * x - 4 * a
    return 0.0


def bicubic_1d(n_in, n_out):
    """[n_out, n_in] weights of PyTorch's bicubic (align_corners=False)."""
    w = np.zeros((n_out, n_in))
    for o in range(n_out):
        src = (o + 0.5) * n_in / n_out - 0.5
        f = math.floor(src)
        t = src - f
        for k in range(-1, 3):
            w[o, min(max(f + k, 0), n_in - 1)] += cubic(k - t)
    return w


def test_position_embedding_is_bicubic_plus_tiled_window():
    g = torch.Generator().manual_seed(0)
    c, side, win = 3, 24, 4
    sd = {"image_encoder.trunk.pos_embed": torch.randn(1, c, 7, 7, generator=g, dtype=D),
          "image_encoder.trunk.pos_embed_window": torch.randn(1, c, win, win, generator=g, dtype=D)}
    got = sam2.position_embedding(sd, None, side)[0].numpy()          # [side, side, c]
    w = bicubic_1d(7, side)
    bg = np.einsum("yi,cij,xj->yxc", w, sd["image_encoder.trunk.pos_embed"][0].numpy(), w)
    tile = sd["image_encoder.trunk.pos_embed_window"][0].numpy()
    want = bg + np.stack([[tile[:, y % win, x % win] for x in range(side)] for y in range(side)])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def block_weights(dim, dim_out, g):
    sd = {}
    for n, shape in (("norm1.weight", (dim,)), ("norm1.bias", (dim,)), ("attn.qkv.weight", (3 * dim_out, dim)),
                     ("attn.qkv.bias", (3 * dim_out,)), ("attn.proj.weight", (dim_out, dim_out)),
                     ("attn.proj.bias", (dim_out,)), ("norm2.weight", (dim_out,)), ("norm2.bias", (dim_out,)),
                     ("mlp.layers.0.weight", (4 * dim_out, dim_out)), ("mlp.layers.0.bias", (4 * dim_out,)),
                     ("mlp.layers.1.weight", (dim_out, 4 * dim_out)), ("mlp.layers.1.bias", (dim_out,)),
                     ("proj.weight", (dim_out, dim)), ("proj.bias", (dim_out,))):
        sd["b." + n] = torch.randn(*shape, generator=g, dtype=D) * (0.5 if "weight" in n else 1.0)
    return sd


def naive_block(x, sd, dim, dim_out, heads, window, q_pool):
    """The block as the spec words it, one window and one head at a time in numpy."""
    p = {k[2:]: v.numpy() for k, v in sd.items()}
    x = x[0].numpy()
    h, w, _ = x.shape

    def ln(v, wt, b):
        m = v.mean(-1, keepdims=True)
        return (v - m) / np.sqrt(((v - m) ** 2).mean(-1, keepdims=True) + 1e-6) * wt + b

    def pool(v):  # 2x2 max over [H, W, C] (H, W even)
        return np.maximum.reduce([v[0::2, 0::2], v[1::2, 0::2], v[0::2, 1::2], v[1::2, 1::2]])
    xn = ln(x, p["norm1.weight"], p["norm1.bias"])
    shortcut = x if dim == dim_out else xn @ p["proj.weight"].T + p["proj.bias"]
    if q_pool:
        shortcut = pool(shortcut)
    hp, wp = -(-h // window) * window, -(-w // window) * window
    padded = np.zeros((hp, wp, dim))
    padded[:h, :w] = xn                                      # pad tokens are zeros before qkv
    qkv = padded @ p["attn.qkv.weight"].T + p["attn.qkv.bias"]
    q, k, v = qkv[..., :dim_out], qkv[..., dim_out:2 * dim_out], qkv[..., 2 * dim_out:]
    hd = dim_out // heads
    ow = window // 2 if q_pool else window
    out = np.zeros((hp // window * ow, wp // window * ow, dim_out))
    for wy in range(hp // window):
        for wx in range(wp // window):
            sl = np.s_[wy * window:(wy + 1) * window, wx * window:(wx + 1) * window]
            qw = pool(q[sl]) if q_pool else q[sl]
            kw, vw = k[sl].reshape(-1, dim_out), v[sl].reshape(-1, dim_out)
            qf = qw.reshape(-1, dim_out)
            o = np.zeros_like(qf)
            for hh in range(heads):
                c = np.s_[hh * hd:(hh + 1) * hd]
                s = qf[:, c] @ kw[:, c].T / math.sqrt(hd)
                e = np.exp(s - s.max(-1, keepdims=True))
                o[:, c] = (e / e.sum(-1, keepdims=True)) @ vw[:, c]
            out[wy * ow:(wy + 1) * ow, wx * ow:(wx + 1) * ow] = o.reshape(ow, ow, dim_out)
    out = out @ p["attn.proj.weight"].T + p["attn.proj.bias"]
    y = shortcut + out[:shortcut.shape[0], :shortcut.shape[1]]
    hid = ln(y, p["norm2.weight"], p["norm2.bias"]) @ p["mlp.layers.0.weight"].T + p["mlp.layers.0.bias"]
    hid = 0.5 * hid * (1 + np.vectorize(math.erf)(hid / math.sqrt(2)))
    return y + hid @ p["mlp.layers.1.weight"].T + p["mlp.layers.1.bias"]


@pytest.mark.parametrize("h,dim,dim_out,heads,window,q_pool", [
    (10, 6, 6, 2, 4, False),    # 10 -> 12: the edge windows hold bias-only pad keys
    (7, 4, 4, 1, 3, False),     # odd window, 7 -> 9
    (10, 4, 8, 2, 6, True),     # transition: q pooled in windows of 6 (10 -> 12, pooled grid 6 -> 5)
])
def test_windowed_block_matches_the_spec(h, dim, dim_out, heads, window, q_pool):
    g = torch.Generator().manual_seed(h + window)
    sd = block_weights(dim, dim_out, g)
    x = torch.randn(1, h, h, dim, generator=g, dtype=D)
    blk = dict(dim=dim, dim_out=dim_out, heads=heads, window=window, q_pool=int(q_pool))
    got = sam2.hiera_block(x, sd, "b.", blk)[0].numpy()
    np.testing.assert_allclose(got, naive_block(x, sd, dim, dim_out, heads, window, q_pool), rtol=0, atol=1e-10)


def test_dense_pe_formula():
    g = torch.Generator().manual_seed(3)
    G = torch.randn(2, 8, generator=g, dtype=D)
    pe = sam2.dense_pe({"sam_prompt_encoder.pe_layer.positional_encoding_gaussian_matrix": G}, 5, D)[0].numpy()
    i, j, k = 3, 1, 6
    x, y = 2 * (j + 0.5) / 5 - 1, 2 * (i + 0.5) / 5 - 1
    arg = 2 * math.pi * (x * G[0, k].item() + y * G[1, k].item())
    assert abs(pe[k, i, j] - math.sin(arg)) < 1e-12 and abs(pe[8 + k, i, j] - math.cos(arg)) < 1e-12


def test_uint8_truncates_and_prompt_is_plus_minus_ten():
    img = torch.full((3, 4, 4), 0.999, dtype=torch.float32)         # 254.745 -> 254, not 255
    x = sam2.preprocess(img, D)
    want = (254 / 255 - sam2.IMAGENET_MEAN[0]) / sam2.IMAGENET_STD[0]
    assert abs(x[0, 0, 500, 500].item() - want) < 1e-12
    prob = torch.tensor([[0.5, 0.5000001], [0.9, 0.1]], dtype=D)
    p = sam2.mask_prompt(prob, D)
    assert p.shape == (1, 1, 256, 256)
    # > 0.5, not >= : the corner pixels of the 2x2 map, far from the bilinear blends
    assert p[0, 0, 0, 0].item() == -10.0 and p[0, 0, 0, 255].item() == 10.0
    assert p[0, 0, 255, 0].item() == 10.0 and p[0, 0, 255, 255].item() == -10.0


@pytest.mark.parametrize("count,skipped", [(9, True), (10, False), (16 * 16 - 10, False), (16 * 16 - 9, True)])
def test_skip_rule_edges(count, skipped, monkeypatch):
    prob = torch.zeros(16 * 16, dtype=D)
    prob[:count] = 0.75
    prob = prob.reshape(16, 16)
    ran = []

    class EncoderRan(Exception):
        pass

    def encoder(*a, **k):
        ran.append(1)
        raise EncoderRan()
    monkeypatch.setattr(sam2, "image_encoder", encoder)
    cfg = Sam2Config("x", 8, 1, [1, 1, 1, 1], [], [8, 4, 4, 2], [7, 7], 32, [64, 32, 16, 8])
    if skipped:
        r = sam2.refine_view({}, cfg, torch.rand(3, 16, 16), prob, D)
        assert r["skipped"] and torch.equal(r["refined"], (prob > 0.5).to(D)) and r["dynamic_pixels"] == count
        assert not ran
    else:
        with pytest.raises(EncoderRan):
            sam2.refine_view({}, cfg, torch.rand(3, 16, 16), prob, D)
        assert ran
