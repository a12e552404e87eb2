#!/usr/bin/python3
"""Tests of the SPAR reference (reference/spar_reference: config, transformer, spar).

Tiny config only; the backbones are small stubs with the DINOv3 / LSeg interfaces, so these
tests do not depend on the backbone references (tested in test_reference_backbones.py).

Run: cd /work/main && /usr/bin/python3 -m pytest -q reference/tests/test_reference_spar.py
"""

import copy
import math

import pytest
import torch
import torch.nn as nn
import torch.nn.functional as F


from spar_reference import config as spar_config  # noqa: E402
from spar_reference import spar  # noqa: E402
from spar_reference.transformer import Block, RMSNorm  # noqa: E402

torch.set_num_threads(1)

# Stated tolerance: float32 vs float64 outputs of every stage of the tiny model, as
# max|a32 - a64| / max|a64| per tensor. Measured ~1e-6 at most (perturbed and official init).
STAGE_RTOL = 1e-5


class DinoStub(nn.Module):
    """DINOv3 interface: images in [0,1] -> normalized patch tokens [B, (H/16)(W/16), D]."""

    def __init__(self, d):
        super().__init__()
        self.register_buffer("mean", torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1))
        self.proj = nn.Conv2d(3, d, 16, 16)
        self.norm = nn.LayerNorm(d)

    def forward(self, x):
        x = (x - self.mean) / self.std
        return self.norm(self.proj(x).flatten(2).transpose(1, 2))


class LSegStub(nn.Module):
    """LSeg interface: images in [0,1] -> features [B, C, H/2, W/2]."""

    def __init__(self, c):
        super().__init__()
        self.conv = nn.Conv2d(3, c, 2, 2)

    def forward(self, x):
        return self.conv(x)


def make_model(cfg=None, seed=0, perturb=True):
    cfg = cfg or spar_config.tiny()
    torch.manual_seed(seed)
    m = spar.SPAR(cfg, dino=DinoStub(cfg.d), lseg=LSegStub(cfg.semantic_dim) if cfg.use_lseg else False)
    if perturb:
        spar.perturb_parameters(m, seed + 1)
    return m.eval()


def images(cfg, v=5, b=1, seed=3):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(b, v, 3, cfg.image_height, cfg.image_width, generator=g)


# ----------------------------------------------------------------------------- key list
def official_keys(cfg):
    """SPAR's own state_dict keys and shapes, written from the official code
    (model/spar.py, rayzer.py PoseEstimator, cv_drp.py, transformer.py), independent of
    the reference implementation."""
    D, S, p, dh = cfg.d, cfg.scene_tokens, cfg.patch_size, cfg.d_head
    C = cfg.semantic_dim
    keys = {
        "scene_code": (S, D), "cam_code": (1, D), "mask_token": (1, 1, D),
        "static_indicator": (1, 1, D), "dynamic_indicator": (1, 1, D),
        "image_tokenizer.1.weight": (D, 3 * p * p),
        "decoder_ln.weight": (D,),
        "pose_predictor.rel_head.0.weight": (D, 2 * D), "pose_predictor.rel_head.0.bias": (D,),
        "pose_predictor.rel_head.2.weight": (9, D), "pose_predictor.rel_head.2.bias": (9,),
        "pose_predictor.canonical_k_head.0.weight": (D, D),
        "pose_predictor.canonical_k_head.0.bias": (D,),
        "pose_predictor.canonical_k_head.2.weight": (1, D),
        "pose_predictor.canonical_k_head.2.bias": (1,),
        "target_pose_tokenizer.1.weight": (D, 6 * p * p),
        "target_pose_tokenizer2.1.weight": (D, 6 * p * p),
        "mlp_fuse.0.weight": (2 * D,), "mlp_fuse.1.weight": (D, 2 * D), "mlp_fuse.1.bias": (D,),
        "mlp_fuse.3.weight": (D, D), "mlp_fuse.3.bias": (D,),
        "image_token_decoder.0.weight": (D,), "image_token_decoder.1.weight": (3 * p * p, D),
        "view_type_embedding.weight": (2, D),
    }
    for name in ("pe_embedder", "temporal_pe_embedder"):
        keys.update({f"{name}.0.weight": (D, D), f"{name}.0.bias": (D,),
                     f"{name}.2.weight": (D, D), f"{name}.2.bias": (D,)})

    def block(prefix, head_dim):
        return {f"{prefix}.norm1.weight": (D,), f"{prefix}.attn.to_qkv.weight": (3 * D, D),
                f"{prefix}.attn.q_norm.weight": (head_dim,),
                f"{prefix}.attn.k_norm.weight": (head_dim,),
                f"{prefix}.attn.fc.weight": (D, D), f"{prefix}.norm2.weight": (D,),
                f"{prefix}.mlp.mlp.0.weight": (4 * D, D), f"{prefix}.mlp.mlp.2.weight": (D, 4 * D)}

    for stack, n in (("transformer_encoder", cfg.encoder_n_layer),
                     ("transformer_encoder_geom", cfg.encoder_geom_n_layer),
                     ("transformer_decoder", cfg.decoder_n_layer)):
        for i in range(n):
            keys.update(block(f"{stack}.{i}", dh))
    e = "cv_drp.estimator"
    Dd = cfg.dino_width
    keys.update({f"{e}.dino_proj.0.weight": (Dd,), f"{e}.dino_proj.0.bias": (Dd,),
                 f"{e}.dino_proj.1.weight": (D, Dd), f"{e}.dino_proj.1.bias": (D,)})
    for name in ("image_proj", "ray_proj"):
        keys.update({f"{e}.{name}.0.weight": (D,), f"{e}.{name}.0.bias": (D,),
                     f"{e}.{name}.1.weight": (D, D), f"{e}.{name}.1.bias": (D,)})
    keys.update({f"{e}.fusion_mlp.net.0.weight": (2 * D, 3 * D), f"{e}.fusion_mlp.net.0.bias": (2 * D,),
                 f"{e}.fusion_mlp.net.2.weight": (D, 2 * D), f"{e}.fusion_mlp.net.2.bias": (D,)})
    for i in range(cfg.cv_drp_n_layer):
        keys.update(block(f"{e}.transformer_layers.{i}", D // cfg.cv_drp_n_heads))

    def bn(prefix, c):
        return {f"{prefix}.weight": (c,), f"{prefix}.bias": (c,), f"{prefix}.running_mean": (c,),
                f"{prefix}.running_var": (c,), f"{prefix}.num_batches_tracked": ()}

    dp = f"{e}.dpt_decoder"
    keys.update({f"{dp}.project.0.weight": (256, D, 1, 1), f"{dp}.project.0.bias": (256,)})
    keys.update(bn(f"{dp}.project.1", 256))
    for k, (ci, co) in enumerate(((256, 128), (128, 64), (64, 32))):
        keys.update({f"{dp}.up_blocks.{k}.0.weight": (ci, co, 2, 2), f"{dp}.up_blocks.{k}.0.bias": (co,),
                     f"{dp}.up_blocks.{k}.3.weight": (co, co, 3, 3), f"{dp}.up_blocks.{k}.3.bias": (co,)})
        keys.update(bn(f"{dp}.up_blocks.{k}.1", co))
        keys.update(bn(f"{dp}.up_blocks.{k}.4", co))
    keys.update({f"{dp}.final_up.0.weight": (32, 16, 2, 2), f"{dp}.final_up.0.bias": (16,),
                 f"{dp}.head.weight": (1, 16, 1, 1), f"{dp}.head.bias": (1,)})
    keys.update(bn(f"{dp}.final_up.1", 16))
    if cfg.use_lseg:
        keys.update({
            "semantic_proj.weight": (D, C + 6), "semantic_proj.bias": (D,),
            "target_pose_tokenizer_semantic.1.weight": (D, 6 * p * p),
            "semantic_token_decoder.0.weight": (D,),
            "semantic_token_decoder.1.weight": (2 * D, D),
            "semantic_token_decoder.3.weight": (4 * D, 2 * D),
            "semantic_token_decoder.5.weight": (p * p * 64, 4 * D),
            "semantic_feature_expansion.1.weight": (C, 64, 1, 1),
            "semantic_feature_expansion.1.bias": (C,),
        })
    return keys


def _odd_config():
    c = spar_config.tiny()
    c.d, c.d_head, c.cv_drp_n_heads, c.scene_tokens = 48, 16, 3, 7
    c.encoder_n_layer, c.encoder_geom_n_layer, c.decoder_n_layer, c.cv_drp_n_layer = 1, 3, 2, 1
    c.dino = dict(c.dino, embed_dim=48)
    c.semantic_dim = 24
    c.lseg = dict(c.lseg, feature_dim=24)
    return c.validate()


@pytest.mark.parametrize("which", ["tiny", "odd", "no_lseg"])
def test_state_dict_keys_and_shapes_match_official(which):
    if which == "tiny":
        cfg = spar_config.tiny()
    elif which == "odd":
        cfg = _odd_config()
    else:
        cfg = spar_config.tiny()
        cfg.use_lseg = False
    m = make_model(cfg, perturb=False)
    own = spar.spar_own_state_dict(m)
    want = official_keys(cfg)
    assert set(own) == set(want), (sorted(set(own) - set(want)), sorted(set(want) - set(own)))
    for k, shape in want.items():
        assert tuple(own[k].shape) == shape, (k, tuple(own[k].shape), shape)
    # backbones sit under the official attribute names
    full = m.state_dict()
    assert "_dino_v3.mean" in full and "_dino_v3.std" in full
    assert any(k.startswith("lseg_model.") for k in full) == cfg.use_lseg


def test_block_defaults_are_spar_block():
    b = Block(64, 32)
    assert sorted(k for k, _ in b.state_dict().items()) == sorted([
        "norm1.weight", "attn.to_qkv.weight", "attn.q_norm.weight", "attn.k_norm.weight",
        "attn.fc.weight", "norm2.weight", "mlp.mlp.0.weight", "mlp.mlp.2.weight"])
    # against a direct formula
    torch.manual_seed(0)
    for p in b.parameters():
        nn.init.normal_(p, std=0.2)
    x = torch.randn(2, 7, 64, dtype=torch.float64)
    b = b.double()
    h = F.layer_norm(x, (64,), b.norm1.weight, None, 1e-5)
    q, k, v = (h @ b.attn.to_qkv.weight.T).chunk(3, -1)
    q, k, v = (t.reshape(2, 7, 2, 32) for t in (q, k, v))
    rms = lambda t, w: t / torch.sqrt(t.pow(2).mean(-1, keepdim=True) + 1e-5) * w  # noqa: E731
    q, k = rms(q, b.attn.q_norm.weight), rms(k, b.attn.k_norm.weight)
    q, k, v = (t.transpose(1, 2) for t in (q, k, v))
    a = torch.softmax(q @ k.transpose(-1, -2) / math.sqrt(32), -1) @ v
    x1 = x + a.transpose(1, 2).reshape(2, 7, 64) @ b.attn.fc.weight.T
    h2 = F.layer_norm(x1, (64,), b.norm2.weight, None, 1e-5)
    ref = x1 + F.gelu(h2 @ b.mlp.mlp[0].weight.T) @ b.mlp.mlp[2].weight.T
    assert torch.allclose(b(x), ref, atol=1e-12, rtol=1e-12)


def test_rmsnorm_fp32_compute_and_zero_head():
    n = RMSNorm(8)
    z = torch.zeros(3, 8, dtype=torch.float16)
    assert torch.all(n(z) == 0)
    x = torch.randn(4, 8, dtype=torch.float64) * 1e3
    y = n.double()(x)
    assert y.dtype == torch.float64
    assert torch.allclose(y, x / torch.sqrt((x * x).mean(-1, keepdim=True) + 1e-5), rtol=1e-14)


# ----------------------------------------------------------------------------- precision
def _flat(o, prefix=""):
    for k, v in o.items():
        if torch.is_tensor(v) and v.is_floating_point():
            yield prefix + k, v
        elif isinstance(v, dict):
            yield from _flat(v, prefix + k + ".")


@pytest.mark.parametrize("perturb", [True, False])
def test_float32_matches_float64_per_stage(perturb):
    m32 = make_model(perturb=perturb)
    m64 = copy.deepcopy(m32).double()
    cfg = m32.cfg
    x = images(cfg)
    with torch.no_grad():
        a = m32(x, [0, 3, 4], [1, 2])
        b = m64(x.double(), [0, 3, 4], [1, 2])
    assert b["rgb"].dtype == torch.float64 and b["semantic_features"].dtype == torch.float64
    ref = dict(_flat(b))
    stages = list(_flat(a))
    assert len(stages) >= 40
    for k, v in stages:
        r = ref[k]
        assert torch.isfinite(v).all(), k
        err = (v.double() - r).abs().max().item() / max(r.abs().max().item(), 1e-30)
        assert err < STAGE_RTOL, (k, err)


# ----------------------------------------------------------------------------- poses
def test_canonical_view_pose_is_identity_and_focal_shared():
    m = make_model()
    cfg = m.cfg
    for v in (2, 5):
        with torch.no_grad():
            o = m(images(cfg, v=v, b=2), list(range(v)), None)
        c = v // 2
        eye = torch.eye(4).expand(2, 4, 4)
        assert torch.equal(o["c2w"][:, c], eye)
        others = [i for i in range(v) if i != c]
        assert not torch.allclose(o["c2w"][:, others], torch.eye(4))  # perturbed heads move them
        k = o["fxfycxcy"]
        assert torch.equal(k[..., 0], k[..., 1])
        assert torch.equal(k[..., 0], k[:, :1, 0].expand_as(k[..., 0]))
        assert torch.all(k[..., 2:] == 0.5)
        # rotations orthonormal, det +1
        r = o["c2w"][..., :3, :3].double()
        assert torch.allclose(r @ r.transpose(-1, -2), torch.eye(3, dtype=torch.float64), atol=1e-6)
        assert torch.allclose(torch.det(r), torch.ones(()).double(), atol=1e-6)


@pytest.mark.parametrize("dtype,tol", [(torch.float32, 2e-6), (torch.float64, 1e-14)])
def test_rot6d_orthonormal_for_nearly_collinear_inputs(dtype, tol):
    g = torch.Generator().manual_seed(0)
    a1 = torch.randn(64, 3, generator=g, dtype=torch.float64)
    rows = []
    for eps in (1e-1, 1e-3, 1e-5, 1e-6):
        noise = torch.randn(64, 3, generator=g, dtype=torch.float64)
        rows.append(torch.cat([a1, a1 * 3.0 + eps * noise], 1))
    rows.append(torch.tensor([[1.0, 0, 0, 1.0, 1e-6, 0], [1e3, 1e3, 1e3, 1e3, 1e3, 1e3 + 1e-1],
                              [1e-6, 0, 0, 0, 1e-6, 0]], dtype=torch.float64))
    x = torch.cat(rows).to(dtype)
    r = spar.rot6d_to_mat(x)
    assert torch.isfinite(r).all()
    eye = torch.eye(3, dtype=dtype)
    err = (r.transpose(-1, -2) @ r - eye).abs().max().item()
    assert err < tol, err
    assert torch.allclose(torch.det(r.double()), torch.ones(()).double(), atol=10 * tol)
    # first column is the normalized first vector
    assert torch.allclose(r[..., 0], F.normalize(x[:, :3], dim=1), atol=tol)
    # identity input -> identity
    i6 = torch.tensor([[1.0, 0, 0, 0, 1, 0]], dtype=dtype)
    assert torch.equal(spar.rot6d_to_mat(i6)[0], eye)


# ----------------------------------------------------------------------------- Plücker rays
def _rays_numpy_like(c2w, k, h, w):
    """float64 direct formula: per pixel d = normalize(R [(x+.5-cx)/fx, (y+.5-cy)/fy, 1])."""
    fx, fy, cx, cy = k[0] * w, k[1] * h, k[2] * w, k[3] * h
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64),
                            indexing="ij")
    cam = torch.stack([(xs + 0.5 - cx) / fx, (ys + 0.5 - cy) / fy, torch.ones_like(xs)], -1)
    d = cam @ c2w[:3, :3].T
    d = d / d.norm(dim=-1, keepdim=True)
    o = c2w[:3, 3].expand_as(d)
    return torch.cat([torch.cross(o, d, dim=-1), d], -1).permute(2, 0, 1)


@pytest.mark.parametrize("focal", [1e-3, 1.25, 1e3])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_plucker_rays_extreme_focal_zero_translation_identical_views(focal, dtype):
    h = w = 32
    ang = 0.3
    rot = torch.tensor([[math.cos(ang), 0, math.sin(ang)], [0, 1, 0],
                        [-math.sin(ang), 0, math.cos(ang)]], dtype=torch.float64)
    c2w = torch.eye(4, dtype=torch.float64).repeat(3, 1, 1)
    c2w[:, :3, :3] = rot
    c2w[1, :3, 3] = torch.tensor([0.5, -2.0, 3.0], dtype=torch.float64)   # view 1 translated
    c2w[2] = c2w[0]                                                      # view 2 == view 0
    k = torch.tensor([focal, focal, 0.5, 0.5], dtype=torch.float64).repeat(3, 1)
    r = spar.plucker_rays(c2w.to(dtype), k.to(dtype), h, w)
    assert r.shape == (3, 6, h, w) and r.dtype == dtype
    assert torch.isfinite(r).all()
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    for i in range(3):
        ref = _rays_numpy_like(c2w[i], k[i], h, w)
        assert torch.allclose(r[i].double(), ref, atol=tol * max(1.0, ref.abs().max().item()))
    d = r[:, 3:].double()
    assert torch.allclose(d.norm(dim=1), torch.ones(3, h, w, dtype=torch.float64), atol=tol)
    # zero translation: zero moment; identical views: identical rays
    assert torch.all(r[0, :3] == 0)
    assert torch.equal(r[0], r[2])
    # moment is orthogonal to the direction
    assert (r[1, :3].double() * d[1]).sum(0).abs().max() < 10 * tol
    if focal == 1e3:   # nearly parallel rays along the optical axis R e_z
        assert torch.allclose(d[0], rot[:, 2].view(3, 1, 1).expand(3, h, w), atol=1e-3)
    if focal == 1e-3:  # nearly lateral rays: tiny z component in camera frame
        cam_z = (d[0] * rot[:, 2].view(3, 1, 1)).sum(0)
        assert cam_z.abs().max() < 0.05   # pixel centres at >= 0.5 px from (cx, cy): |x/fx| >= 15


# ----------------------------------------------------------------------------- gating
def test_gating_all_dynamic_gives_mask_codes_and_all_static_keeps_tokens():
    m = make_model()
    cfg = m.cfg
    x = images(cfg)
    n = cfg.tokens_per_view
    hh, ww = cfg.patches_h, cfg.patches_w
    ones = torch.ones(1, 3, 1, cfg.image_height, cfg.image_width)
    with torch.no_grad():
        dyn = m(x, [0, 3, 4], [1, 2], dynamic_mask=ones)
        sta = m(x, [0, 3, 4], [1, 2], dynamic_mask=torch.zeros_like(ones))
    pe = spar.sincos_2d(cfg.d, hh, ww)
    want = (m.mask_token[0, 0][None] + pe).repeat(3, 1)[None]
    assert torch.equal(dyn["gated_tokens"], want)
    assert torch.equal(sta["gated_tokens"], sta["fused_tokens"])
    want_sem = (m.mask_token[0, 0][None] + spar.sincos_2d(cfg.d, cfg.image_height // 16,
                                                          cfg.image_width // 16)).repeat(3, 1)[None]
    assert torch.equal(dyn["gated_semantic_tokens"], want_sem)
    assert torch.equal(sta["gated_semantic_tokens"], sta["semantic_tokens"])
    assert dyn["gated_tokens"].shape == (1, 3 * n, cfg.d)
    # a soft mask blends linearly, per 16x16 patch
    half = torch.full_like(ones, 0.25)
    with torch.no_grad():
        mid = m(x, [0, 3, 4], [1, 2], dynamic_mask=half)
    blend = 0.75 * sta["fused_tokens"] + 0.25 * want
    assert torch.allclose(mid["gated_tokens"], blend, atol=1e-6)


def test_gating_order_is_free_of_cancellation():
    """P_m ~ 0.01 (official init): the fp32 mask weight must match float64 closely."""
    m = make_model(perturb=False)
    cfg = m.cfg
    tok = torch.randn(1, 3 * cfg.tokens_per_view, cfg.d)
    p = torch.full((1, 3 * cfg.tokens_per_view), 0.0100001)
    a = m.gate(tok, p, 3, cfg.patches_h, cfg.patches_w)
    b = copy.deepcopy(m).double().gate(tok.double(), p.double(), 3, cfg.patches_h, cfg.patches_w)
    assert ((a.double() - b).abs().max() / b.abs().max()).item() < 1e-6


# ----------------------------------------------------------------------------- CV-DRP pairs
def test_view_pairs_and_logit_average_before_sigmoid():
    assert spar.get_view_pairs(3, "input") == [(0, 1), (1, 2)]
    assert spar.get_view_pairs(1, "input") == [(0, 0)]
    assert spar.get_view_pairs(4, "target") == [(0, 3), (1, 2)]
    assert spar.get_view_pairs(5, "target") == [(0, 4), (1, 3), (2, 1)]
    assert spar.get_view_pairs(1, "target") == [(0, 0)]
    m = make_model()
    cfg = m.cfg
    with torch.no_grad():
        o = m(images(cfg, v=6), [0, 2, 5], [1, 3, 4])
    ci = o["cv_drp_input"]
    pl = ci["pair_logits"]                                       # pairs (0,1), (1,2)
    assert torch.allclose(ci["logits"][:, 1], 0.5 * (pl[0][:, 1] + pl[1][:, 0]), atol=1e-6)
    assert torch.equal(ci["logits"][:, 0], pl[0][:, 0])
    assert torch.equal(ci["prob"], torch.sigmoid(ci["logits"]))
    ct = o["cv_drp_target"]                                      # pairs (0,2), (1,0)
    assert ct["pairs"] == [(0, 2), (1, 0)]
    tl = ct["pair_logits"]
    assert torch.allclose(ct["logits"][:, 0], 0.5 * (tl[0][:, 0] + tl[1][:, 1]), atol=1e-6)
    assert torch.equal(ct["logits"][:, 1], tl[1][:, 0])
    assert torch.equal(ct["logits"][:, 2], tl[0][:, 1])
    assert ct["logits"].shape == (1, 3, 1, cfg.image_height, cfg.image_width)


def test_pose_encoder_sees_all_views_in_sequence_order():
    """Interleaving matters: inputs [0,3,4] / targets [1,2] of one sequence differ from the
    same frames given as inputs first."""
    m = make_model()
    cfg = m.cfg
    x = images(cfg)
    with torch.no_grad():
        a = m(x, [0, 3, 4], [1, 2])
        b = m(x[:, [0, 3, 4, 1, 2]], [0, 1, 2], [3, 4])
    assert not torch.allclose(a["scene_tokens"], b["scene_tokens"], atol=1e-4)
    assert torch.equal(a["c2w"][:, 2], torch.eye(4)[None])   # canonical is frame 2, a target


# ----------------------------------------------------------------------------- rendering mode
def test_explicit_render_cameras():
    m = make_model()
    cfg = m.cfg
    x = images(cfg)
    with torch.no_grad():
        a = m(x, [0, 3, 4], [1, 2])
        b = m(x, [0, 3, 4], [1, 2], render_c2w=a["render_c2w"], render_fxfycxcy=a["render_fxfycxcy"])
        # rendering mode: inputs only in the sequence, novel cameras given explicitly
        c = m(x[:, [0, 3, 4]], [0, 1, 2], None, render_c2w=a["c2w"][:, :1].repeat(1, 3, 1, 1),
              render_fxfycxcy=a["fxfycxcy"][:, :1].repeat(1, 3, 1))
    assert torch.allclose(a["rgb"], b["rgb"], atol=1e-6)
    assert torch.allclose(a["semantic_features"], b["semantic_features"], atol=1e-6)
    assert c["cv_drp_target"] is None
    assert c["rgb"].shape == (1, 3, 3, cfg.image_height, cfg.image_width)
    assert torch.allclose(c["rgb"][:, 0], c["rgb"][:, 2], atol=1e-6)
    assert (c["rgb"] >= 0).all() and (c["rgb"] <= 1).all()
    # RGB without semantic queries differs (joint attention in the decoder)
    with torch.no_grad():
        d = m(x, [0, 3, 4], [1, 2], semantic_queries=False)
    assert "semantic_features" not in d
    assert not torch.allclose(d["rgb"], a["rgb"], atol=1e-6)


def test_patchify_layout_channel_fastest():
    p = spar.Patchify(16)
    x = torch.arange(2 * 3 * 32 * 48, dtype=torch.float64).reshape(1, 2, 3, 32, 48)
    t = p(x)
    assert t.shape == (2, 6, 16 * 16 * 3)
    v, tok, py, px, ch = 1, 4, 5, 7, 2   # token 4 = row 1, col 1
    assert t[v, tok, (py * 16 + px) * 3 + ch] == x[0, v, ch, 16 + py, 16 + px]
    back = spar.unpatchify(t, 1, 2, 2, 3, 16, 3)
    assert torch.equal(back, x)


# ----------------------------------------------------------------------------- config
def test_config_presets_and_official_yaml(tmp_path):
    f = spar_config.full()
    assert (f.d, f.n_heads, f.d_head, f.encoder_n_layer, f.encoder_geom_n_layer,
            f.decoder_n_layer, f.cv_drp_n_layer, f.scene_tokens, f.image_size, f.patch_size,
            f.num_views, f.semantic_dim) == (768, 12, 64, 12, 8, 12, 4, 768, 256, 16, 8, 512)
    t = spar_config.tiny()
    assert (t.d, t.n_heads, t.d_head, t.scene_tokens, t.image_size, t.dino_width) == (64, 2, 32, 16, 128, 64)
    for key in ("dino", "lseg", "clip"):
        assert isinstance(getattr(t, key), dict)
    yaml_text = """
model:
  image_tokenizer: {image_size: 256, patch_size: 16, in_channels: 3}
  input_with_pe: true
  target_image: {height: 256, width: 256, patch_size: 16, in_channels: 6}
  transformer: {d: 768, d_head: 64, encoder_n_layer: 12, encoder_geom_n_layer: 8,
                decoder_n_layer: 12, special_init: true, depth_init: true, use_qk_norm: true}
  scene_latent: {length: 768}
  pose_latent: {length: 1, canonical: middle, representation: '6d'}
  dino_v3: {arch: vitb16, embed_dim: 768}
  cv_drp: {mask_threshold: 0.5, vit_n_heads: 12, vit_n_layers: 4}
  lseg: {checkpoint_path: ./x.ckpt, feature_dim: 512, feature_loss_weight: 0.1}
training: {num_views: 8, num_input_views: 2, num_target_views: 6, semantic_loss_weight: 0.1}
"""
    p = tmp_path / "spar.yaml"
    p.write_text(yaml_text)
    y = spar_config.get_config(str(p))
    for fld in ("d", "d_head", "encoder_n_layer", "encoder_geom_n_layer", "decoder_n_layer",
                "cv_drp_n_layer", "cv_drp_n_heads", "scene_tokens", "image_height", "patch_size",
                "num_views", "semantic_dim", "use_lseg", "canonical", "use_qk_norm"):
        assert getattr(y, fld) == getattr(f, fld), fld
    j = tmp_path / "tiny.json"
    t.save(str(j))
    assert spar_config.get_config(str(j)) == t


# ----------------------------------------------------------------------------- checkpoint
def test_make_checkpoint_structure_and_strict_reload(tmp_path):
    cfg = spar_config.tiny()
    ck = spar.make_checkpoint(cfg, seed=5, perturb=True, dino=DinoStub(cfg.d),
                              lseg=LSegStub(cfg.semantic_dim), step=7)
    assert set(ck) == {"model", "optimizer", "lr_scheduler", "fwdbwd_pass_step", "param_update_step"}
    assert ck["fwdbwd_pass_step"] == 7 and ck["param_update_step"] == 7
    sd = ck["model"]
    for k, v in sd.items():
        if k.endswith("num_batches_tracked"):
            assert v.dtype == torch.int64
        else:
            assert v.dtype == torch.float32, k
    assert set(spar.spar_own_state_dict(make_model(cfg, perturb=False))) <= set(sd)
    groups = ck["optimizer"]["param_groups"]
    assert [g["name"] for g in groups] == ["default", "default_nodecay"]
    assert groups[0]["weight_decay"] == 0.05 and groups[1]["weight_decay"] == 0.0
    n_trainable = sum(len(g["params"]) for g in groups)
    own_params = [k for k, _ in make_model(cfg, perturb=False).named_parameters()
                  if not (k.startswith("_dino_v3.") or k.startswith("lseg_model."))]
    assert n_trainable == len(own_params)
    assert len(ck["optimizer"]["state"]) == n_trainable
    assert ck["lr_scheduler"]["last_epoch"] == 7
    # perturbed: biases, BN statistics and the CV-DRP head are no longer the official init
    assert sd["mlp_fuse.1.bias"].abs().max() > 0
    assert not torch.equal(sd["cv_drp.estimator.dpt_decoder.project.1.running_var"], torch.ones(256))
    assert sd["cv_drp.estimator.dpt_decoder.head.bias"].item() != -4.6
    # official init: zero biases, BN (0, 1), head bias -4.6
    ck0 = spar.make_checkpoint(cfg, seed=5, dino=DinoStub(cfg.d), lseg=LSegStub(cfg.semantic_dim),
                               step=1, optimizer_state=False)
    sd0 = ck0["model"]
    assert torch.all(sd0["mlp_fuse.1.bias"] == 0)
    assert torch.all(sd0["cv_drp.estimator.dpt_decoder.project.1.running_mean"] == 0)
    assert torch.allclose(sd0["cv_drp.estimator.dpt_decoder.head.bias"], torch.tensor([-4.6]))
    # same seed -> same weights (SPAR's own; the stubs are built outside the seed)
    ck1 = spar.make_checkpoint(cfg, seed=5, dino=DinoStub(cfg.d), lseg=LSegStub(cfg.semantic_dim),
                               step=1, optimizer_state=False)
    own = [k for k in sd0 if not (k.startswith("_dino_v3.") or k.startswith("lseg_model."))]
    assert all(torch.equal(sd0[k], ck1["model"][k]) for k in own)
    ck2 = spar.make_checkpoint(cfg, seed=6, dino=DinoStub(cfg.d), lseg=LSegStub(cfg.semantic_dim),
                               step=1, optimizer_state=False)
    assert not torch.equal(sd0["scene_code"], ck2["model"]["scene_code"])
    # save / load round trip and strict reload into the reference
    path = tmp_path / "ckpt_spar_000000000007.pt"
    torch.save(ck, path)
    back = torch.load(path, map_location="cpu")
    m = spar.load_spar(cfg, back["model"], dino=DinoStub(cfg.d), lseg=LSegStub(cfg.semantic_dim))
    with torch.no_grad():
        o = m(images(cfg), [0, 3, 4], [1, 2])
    assert torch.isfinite(o["rgb"]).all()
    bad = dict(back["model"])
    bad.pop("mlp_fuse.1.bias")
    with pytest.raises(RuntimeError):
        spar.load_spar(cfg, bad, dino=DinoStub(cfg.d), lseg=LSegStub(cfg.semantic_dim))


def test_record_layers():
    m = make_model()
    cfg = m.cfg
    with torch.no_grad():
        o = m(images(cfg), [0, 3, 4], [1, 2], record_layers=True)
    lay = o["layers"]
    assert len(lay["transformer_encoder"]) == cfg.encoder_n_layer
    assert len(lay["transformer_encoder_geom"]) == cfg.encoder_geom_n_layer
    assert len(lay["transformer_decoder"]) == cfg.decoder_n_layer
    assert torch.equal(lay["transformer_encoder"][-1], o["pose_encoder_out"])
    assert torch.equal(lay["transformer_encoder_geom"][-1], o["scene_encoder_out"])
    assert torch.equal(lay["transformer_decoder"][-1], o["decoder_out"])


def _real_backbones_available():
    try:
        from spar_reference import dino_v3, lseg  # noqa: F401
        return hasattr(dino_v3, "DinoV3") and hasattr(lseg, "LSegEncoder")
    except Exception:
        return False


@pytest.mark.skipif(not _real_backbones_available(), reason="backbone references not present")
def test_checkpoint_with_real_backbones_round_trip(tmp_path):
    """make_checkpoint with the real tiny DINOv3 / LSeg references: official prefixes,
    torch.save / torch.load, strict reload, float32 vs float64 on the main outputs."""
    cfg = spar_config.tiny()
    ck = spar.make_checkpoint(cfg, seed=2, perturb=True, step=3, optimizer_state=False)
    sd = ck["model"]
    assert "_dino_v3.mean" in sd and "_dino_v3.std" in sd
    assert any(k.startswith("_dino_v3.model.") for k in sd)
    assert any(k.startswith("lseg_model.") for k in sd)
    path = tmp_path / "ckpt_spar_000000000003.pt"
    torch.save(ck, path)
    back = torch.load(path, map_location="cpu")
    m = spar.load_spar(cfg, back["model"])
    for k, v in m.state_dict().items():
        assert torch.equal(v, sd[k]), k
    m64 = copy.deepcopy(m).double()
    x = images(cfg, v=4)
    with torch.no_grad():
        a = m(x, [0, 3], [1, 2])
        b = m64(x.double(), [0, 3], [1, 2])
    for k in ("dino", "lseg_features", "cam_info", "cv_drp_input.prob", "gated_tokens",
              "scene_tokens", "rgb", "semantic_features"):
        if "." in k:
            k1, k2 = k.split(".")
            va, vb = a[k1][k2], b[k1][k2]
        else:
            va, vb = a[k], b[k]
        err = ((va.double() - vb).abs().max() / vb.abs().max()).item()
        assert err < STAGE_RTOL, (k, err)


@pytest.mark.skipif(not _real_backbones_available(), reason="backbone references not present")
def test_backbones_without_initial_values_are_the_same():
    """make_checkpoint(backbone_init=False) skips torch.nn.init inside the backbones: their
    seeded randomization sets every one of their tensors, so DINOv3's and LSeg's are equal bit
    for bit to the default's (and finite); only SPAR's own, drawn later from the global
    generator, may differ."""
    cfg = spar_config.tiny()
    a = spar.make_checkpoint(cfg, seed=4, perturb=True, step=1, optimizer_state=False)["model"]
    b = spar.make_checkpoint(cfg, seed=4, perturb=True, step=1, optimizer_state=False,
                             backbone_init=False)["model"]
    assert a.keys() == b.keys()
    backbone = [k for k in a if k.startswith(("_dino_v3.", "lseg_model."))]
    assert backbone
    for k in backbone:
        assert torch.equal(a[k], b[k]), k
        if b[k].is_floating_point():
            assert torch.isfinite(b[k]).all(), k


def test_sincos_codes_follow_official_grid():
    """pe_utils: 1D code concat(sin(p f), cos(p f)), f_k = 10000^(-k/(dim/2)); 2D code built
    from meshgrid(arange(gw), arange(gh), 'ij') flattened (non-square grid included)."""
    pos = torch.arange(7, dtype=torch.float64)
    f = 1.0 / 10000.0 ** (torch.arange(4, dtype=torch.float64) / 4)
    want1 = torch.cat([torch.sin(pos[:, None] * f), torch.cos(pos[:, None] * f)], -1)
    assert torch.allclose(spar.sincos_1d(8, pos, torch.float64), want1, atol=1e-15)
    for gh, gw in ((4, 4), (3, 5), (5, 2)):
        gy = torch.arange(gh, dtype=torch.float64)
        gx = torch.arange(gw, dtype=torch.float64)
        grid = torch.stack(torch.meshgrid(gx, gy, indexing="ij"), 0)
        grid = grid.reshape(2, 1, grid.shape[1], grid.shape[2])
        a, b = grid[0].reshape(-1), grid[1].reshape(-1)
        want2 = torch.cat([spar.sincos_1d(8, a, torch.float64), spar.sincos_1d(8, b, torch.float64)], -1)
        assert torch.equal(spar.sincos_2d(16, gh, gw, torch.float64), want2)
    # square grid: first half encodes the row, second half the column of token row*W + col
    c = spar.sincos_2d(16, 4, 4, torch.float64)
    assert torch.equal(c[1 * 4 + 3, :8], spar.sincos_1d(8, torch.tensor([1.0]), torch.float64)[0])
    assert torch.equal(c[1 * 4 + 3, 8:], spar.sincos_1d(8, torch.tensor([3.0]), torch.float64)[0])


@pytest.mark.parametrize("variant", ["canonical_first", "quat", "per_scene", "learnable_plucker",
                                     "zero_out", "learnable_indicator", "none", "no_pe"])
def test_official_option_variants_run(variant):
    cfg = spar_config.tiny()
    if variant == "canonical_first":
        cfg.canonical = "first"
    elif variant == "quat":
        cfg.pose_representation = "quat"
    elif variant == "per_scene":
        cfg.plucker_norm_mode = "per_scene"
    elif variant == "learnable_plucker":
        cfg.plucker_norm_mode = "learnable"
    elif variant == "no_pe":
        cfg.input_with_pe = False
    else:
        cfg.input_masking_mode = variant
    m = make_model(cfg)
    if variant == "learnable_plucker":
        assert "log_plucker_scale" in m.state_dict()
    if variant == "quat":
        assert m.state_dict()["pose_predictor.rel_head.2.weight"].shape[0] == 7
    if variant == "no_pe":
        assert not any(k.startswith("pe_embedder.") for k in m.state_dict())
    with torch.no_grad():
        o = m(images(cfg), [0, 3, 4], [1, 2])
    assert torch.isfinite(o["rgb"]).all()
    can = 0 if variant == "canonical_first" else 2
    assert torch.equal(o["c2w"][:, can], torch.eye(4)[None])
    if variant == "per_scene":
        assert o["plucker"][:, :, :3].abs().max() <= 1.0 + 1e-6
    if variant == "none":
        assert torch.equal(o["gated_tokens"], o["fused_tokens"])
