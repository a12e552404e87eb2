#!/usr/bin/python3
"""PyTorch reference of SPAR's own modules, with the official module structure and
state_dict key names (``dmucby/SPAR``: model/spar.py, model/rayzer.py, model/cv_drp.py,
model/transformer.py, utils/pe_utils.py, utils/pose_utils.py). Written from those files,
not copied. Where the architecture page (/work/shared/spar-architecture.md) and the files
disagree, the files win; such points are marked "OFFICIAL:" below.

Backbones are not written here: DINOv3 comes from ``dino_v3.DinoV3`` (held as ``_dino_v3``,
keys ``_dino_v3.mean``, ``_dino_v3.std``, ``_dino_v3.model.*``, like the official
``DINOv3FeatureExtractor`` wrapper) and LSeg from ``lseg.LSegEncoder`` (held as
``lseg_model``, the official attribute name, so an official training checkpoint's
``lseg_model.*`` keys land there). Any module with the same forward interface can be passed
instead (tests use small stubs).

``SPAR.forward`` takes all frames as ONE ordered sequence (capture order) plus the index lists
of input and target views, and returns a dict with every stage's output (see ``forward``).
"""

from __future__ import annotations

import contextlib
import functools
import math
import warnings
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import torch
import torch.nn as nn
import torch.nn.functional as F

from .config import SparConfig
from .transformer import LayerNorm, spar_block

IndexLike = Union[Sequence[int], torch.Tensor]


# ============================================================================ helpers
class Patchify(nn.Module):
    """einops 'b v c (hh ph) (ww pw) -> (b v) (hh ww) (ph pw c)' (channel fastest)."""

    def __init__(self, patch: int):
        super().__init__()
        self.patch = patch

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, v, c, h, w = x.shape
        p = self.patch
        x = x.reshape(b * v, c, h // p, p, w // p, p)
        x = x.permute(0, 2, 4, 3, 5, 1)  # (bv, hh, ww, ph, pw, c)
        return x.reshape(b * v, (h // p) * (w // p), p * p * c)


def unpatchify(x: torch.Tensor, b: int, v: int, hh: int, ww: int, p: int, c: int) -> torch.Tensor:
    """einops '(b v) (h w) (p1 p2 c) -> b v c (h p1) (w p2)'."""
    x = x.reshape(b, v, hh, ww, p, p, c)
    x = x.permute(0, 1, 6, 2, 4, 3, 5)
    return x.reshape(b, v, c, hh * p, ww * p)


def sincos_1d(dim: int, pos: torch.Tensor, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """utils/pe_utils.get_1d_sincos_pos_emb_from_grid: concat(sin(p f), cos(p f)),
    f_k = 10000^(-k/(dim/2)). The official code computes in fp32; here in ``dtype``
    (fp32 for the fp32 model, float64 in float64 mode)."""
    assert dim % 2 == 0
    half = dim // 2
    k = torch.arange(half, dtype=dtype, device=pos.device)
    freq = 1.0 / (10000.0 ** (k / half))
    ang = pos.to(dtype)[:, None] * freq[None, :]
    return torch.cat([torch.sin(ang), torch.cos(ang)], dim=-1)


def sincos_2d(dim: int, grid_h: int, grid_w: int, dtype: torch.dtype = torch.float32,
              device=None) -> torch.Tensor:
    """utils/pe_utils.get_2d_sincos_pos_embed, row-major tokens (k = row*grid_w + col):
    [grid_h*grid_w, dim] = concat(1D code (dim/2) of a, 1D code (dim/2) of b).

    OFFICIAL: the grid is built as meshgrid(arange(grid_w), arange(grid_h), 'ij') and
    flattened, so token k gets a = k // grid_h and b = k % grid_h. For the square grids SPAR
    uses that is (row, column) as the architecture page says; for non-square grids it is not,
    and this function reproduces the official values."""
    n = grid_h * grid_w
    kk = torch.arange(n, device=device)
    a = torch.div(kk, grid_h, rounding_mode="floor")
    b = kk % grid_h
    return torch.cat([sincos_1d(dim // 2, a, dtype), sincos_1d(dim // 2, b, dtype)], dim=-1)


def rot6d_to_mat(x: torch.Tensor, reorthogonalize: bool = True) -> torch.Tensor:
    """utils/pose_utils.rot6d2mat: Gram-Schmidt of a1, a2; columns b1, b2, b1 x b2.

    ``reorthogonalize`` repeats the projection of b2 once ("twice is enough"): exact arithmetic
    gives the same matrix, but for nearly collinear a1, a2 the single official pass loses
    orthogonality in floating point. Deviation from the official numerics at rounding level
    only."""
    a1, a2 = x[:, 0:3], x[:, 3:6]
    b1 = F.normalize(a1, dim=1)
    b2 = a2 - (b1 * a2).sum(-1, keepdim=True) * b1
    if reorthogonalize:
        b2 = b2 - (b1 * b2).sum(-1, keepdim=True) * b1
    b2 = F.normalize(b2, dim=1)
    b3 = torch.cross(b1, b2, dim=1)
    return torch.stack([b1, b2, b3], dim=-1)


def quat_to_mat(q: torch.Tensor) -> torch.Tensor:
    """utils/pose_utils.quat2mat (w, x, y, z), normalized first."""
    q = q / q.norm(p=2, dim=1, keepdim=True)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return torch.stack([
        w * w + x * x - y * y - z * z, 2 * x * y - 2 * w * z, 2 * w * y + 2 * x * z,
        2 * w * z + 2 * x * y, w * w - x * x + y * y - z * z, 2 * y * z - 2 * w * x,
        2 * x * z - 2 * w * y, 2 * w * x + 2 * y * z, w * w - x * x - y * y + z * z,
    ], dim=1).reshape(-1, 3, 3)


def cam_info_to_se3(cam_info: torch.Tensor, reorthogonalize: bool = True
                    ) -> Tuple[torch.Tensor, torch.Tensor]:
    """model/rayzer.get_cam_se3: [N, 13] (6D rot, t, fx fy cx cy) or [N, 11] (quat) ->
    c2w [N, 4, 4], fxfycxcy [N, 4] (normalized intrinsics)."""
    n, m = cam_info.shape
    if m == 13:
        r = rot6d_to_mat(cam_info[:, :6], reorthogonalize)
        t = cam_info[:, 6:9]
        k = cam_info[:, 9:]
    elif m == 11:
        r = quat_to_mat(cam_info[:, :4])
        t = cam_info[:, 4:7]
        k = cam_info[:, 7:]
    else:
        raise ValueError(f"cam_info width {m}")
    c2w = torch.zeros(n, 4, 4, dtype=cam_info.dtype, device=cam_info.device)
    c2w[:, :3, :3] = r
    c2w[:, :3, 3] = t
    c2w[:, 3, 3] = 1.0
    return c2w, k


def plucker_rays(c2w: torch.Tensor, fxfycxcy: torch.Tensor, height: int, width: int,
                 normalized: bool = True) -> torch.Tensor:
    """model/rayzer.cam_info_to_plucker: c2w [N,4,4], fxfycxcy [N,4] -> [N, 6, H, W]
    channels [o x d, d]; pixel centres (x+0.5, y+0.5); normalized intrinsics times W, H;
    d = normalize(R [(x+0.5-cx)/fx, (y+0.5-cy)/fy, 1]); o = translation of c2w."""
    n = c2w.shape[0]
    k = fxfycxcy.clone()
    if normalized:
        k[:, 0] = k[:, 0] * width
        k[:, 1] = k[:, 1] * height
        k[:, 2] = k[:, 2] * width
        k[:, 3] = k[:, 3] * height
    ys, xs = torch.meshgrid(torch.arange(height), torch.arange(width), indexing="ij")
    xs = xs.to(c2w).reshape(1, -1)
    ys = ys.to(c2w).reshape(1, -1)
    x = (xs + 0.5 - k[:, 2:3]) / k[:, 0:1]
    y = (ys + 0.5 - k[:, 3:4]) / k[:, 1:2]
    d = torch.stack([x, y, torch.ones_like(x)], dim=2)            # [N, HW, 3]
    d = torch.bmm(d, c2w[:, :3, :3].transpose(1, 2))
    d = d / torch.norm(d, dim=2, keepdim=True)
    o = c2w[:, :3, 3][:, None, :].expand_as(d)
    o = o.reshape(n, height, width, 3).permute(0, 3, 1, 2)
    d = d.reshape(n, height, width, 3).permute(0, 3, 1, 2)
    return torch.cat([torch.cross(o, d, dim=1), d], dim=1)


def get_view_pairs(n_views: int, mode: str) -> List[Tuple[int, int]]:
    """SPAR._get_view_pairs. OFFICIAL: with an odd number of target views the middle one is
    also paired with its predecessor, (mid, max(0, mid-1)); one view pairs with itself."""
    if mode == "input":
        if n_views <= 1:
            return [(0, 0)]
        return [(i, i + 1) for i in range(n_views - 1)]
    if mode == "target":
        pairs = [(i, n_views - 1 - i) for i in range(n_views // 2)]
        if n_views % 2 == 1:
            mid = n_views // 2
            pairs.append((mid, max(0, mid - 1)))
        return pairs
    raise ValueError(mode)


def _init_linear(module: nn.Module, std: float = 0.02) -> None:
    """Official transformer.init_weights / _init_weights_layerwise: Linear and Embedding
    weights N(0, std), Linear biases 0 (convolutions keep PyTorch's default)."""
    if isinstance(module, (nn.Linear, nn.Embedding)):
        nn.init.normal_(module.weight, mean=0.0, std=std)
        if isinstance(module, nn.Linear) and module.bias is not None:
            nn.init.zeros_(module.bias)


def _mlp2(d_in: int, d_hidden: int, d_out: int) -> nn.Sequential:
    """Linear -> SiLU -> Linear with biases (pe_embedder, temporal_pe_embedder, heads)."""
    return nn.Sequential(nn.Linear(d_in, d_hidden), nn.SiLU(), nn.Linear(d_hidden, d_out))


# ============================================================================ pose
class PoseEstimator(nn.Module):
    """model/rayzer.PoseEstimator (``pose_predictor.*``)."""

    F_BIAS = 1.25

    def __init__(self, cfg: SparConfig):
        super().__init__()
        self.canonical = cfg.canonical
        self.pose_rep = cfg.pose_representation
        self.n_pose = 6 if self.pose_rep == "6d" else 4
        d = cfg.d
        self.rel_head = _mlp2(2 * d, d, self.n_pose + 3)
        self.canonical_k_head = _mlp2(d, d, 1)
        self.rel_head.apply(functools.partial(_init_linear, std=1e-3))
        self.canonical_k_head.apply(functools.partial(_init_linear, std=1e-3))

    def canonical_index(self, v: int) -> int:
        return 0 if self.canonical == "first" else v // 2

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x: [B, V, D] camera tokens -> cam_info [B, V, n_pose+3+4]."""
        b, v, _ = x.shape
        ci = self.canonical_index(v)
        rel = [i for i in range(v) if i != ci]
        x_can = x[:, ci]                                              # [B, D]
        f = self.canonical_k_head(x_can) + self.F_BIAS                # [B, 1]
        fxfy = f.unsqueeze(1).expand(b, v, 2)                         # shared focal, fx = fy
        if self.pose_rep == "6d":
            base = torch.tensor([1, 0, 0, 0, 1, 0, 0, 0, 0], dtype=x.dtype, device=x.device)
        else:
            base = torch.tensor([1, 0, 0, 0, 0, 0, 0], dtype=x.dtype, device=x.device)
        rt = base.reshape(1, 1, -1).repeat(b, v, 1)
        if rel:
            feat = torch.cat([x_can[:, None].expand(b, len(rel), -1), x[:, rel]], dim=-1)
            delta = self.rel_head(feat)
            rt = rt.clone()
            rt[:, rel] = rt[:, rel] + delta
        cxcy = torch.full((b, v, 2), 0.5, dtype=x.dtype, device=x.device)
        return torch.cat([rt, fxfy, cxcy], dim=-1)


# ============================================================================ CV-DRP
class FusionMLP(nn.Module):
    def __init__(self, d_in: int, d_out: int, hidden_ratio: float = 2.0):
        super().__init__()
        h = int(d_out * hidden_ratio)
        self.net = nn.Sequential(nn.Linear(d_in, h), nn.GELU(), nn.Linear(h, d_out))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class DPTDecoder(nn.Module):
    """model/cv_drp.DPTDecoder: patch tokens -> one logit per pixel (x16 upsampling).
    Channels 256, 128, 64, 32, 16 are hard-coded in the official code, whatever D is."""

    CHANNELS = (256, 128, 64, 32)

    def __init__(self, d_model: int):
        super().__init__()
        ch = self.CHANNELS
        self.project = nn.Sequential(nn.Conv2d(d_model, ch[0], 1), nn.BatchNorm2d(ch[0]), nn.GELU())
        self.up_blocks = nn.ModuleList()
        cin = ch[0]
        for cout in ch[1:]:
            self.up_blocks.append(nn.Sequential(
                nn.ConvTranspose2d(cin, cout, kernel_size=2, stride=2),
                nn.BatchNorm2d(cout), nn.GELU(),
                nn.Conv2d(cout, cout, 3, padding=1),
                nn.BatchNorm2d(cout), nn.GELU(),
            ))
            cin = cout
        self.final_up = nn.Sequential(nn.ConvTranspose2d(ch[-1], 16, kernel_size=2, stride=2),
                                      nn.BatchNorm2d(16), nn.GELU())
        self.head = nn.Conv2d(16, 1, kernel_size=1)
        for m in self.modules():
            if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d)):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)
        nn.init.normal_(self.head.weight, std=0.01)
        nn.init.constant_(self.head.bias, -4.6)

    def forward(self, tokens: torch.Tensor, h: int, w: int) -> torch.Tensor:
        n = tokens.shape[0]
        x = tokens.transpose(1, 2).reshape(n, -1, h, w)
        x = self.project(x)
        for blk in self.up_blocks:
            x = blk(x)
        x = self.final_up(x)
        return self.head(x)                                           # [N, 1, 16h, 16w]


class CVDRPFusion(nn.Module):
    """model/cv_drp.CVDRPFusion (``cv_drp.estimator.*``)."""

    def __init__(self, d: int, n_heads: int, n_layers: int, d_dino: int):
        super().__init__()
        # OFFICIAL: dino_proj / image_proj / ray_proj exist (LayerNorm with bias + Linear) but
        # forward never uses them; they are kept so the key list matches.
        self.dino_proj = nn.Sequential(nn.LayerNorm(d_dino), nn.Linear(d_dino, d))
        self.image_proj = nn.Sequential(nn.LayerNorm(d), nn.Linear(d, d))
        self.ray_proj = nn.Sequential(nn.LayerNorm(d), nn.Linear(d, d))
        self.fusion_mlp = FusionMLP(3 * d, d, 2.0)
        self.transformer_layers = nn.ModuleList(
            [spar_block(d, d // n_heads, True) for _ in range(n_layers)])
        self.dpt_decoder = DPTDecoder(d)
        for name, mod in self.named_modules():
            if "dpt_decoder" not in name:
                _init_linear(mod, 0.02)

    def forward(self, dino: torch.Tensor, img: torch.Tensor, ray: torch.Tensor,
                h: int, w: int) -> Dict[str, torch.Tensor]:
        """dino, img, ray: [B, V, N, D] -> dict(fused [B, V*N, D], tokens [B, V*N, D],
        logits [B, V, 1, 16h, 16w])."""
        b, v, n, _ = dino.shape
        fused = self.fusion_mlp(torch.cat([dino, img, ray], dim=-1)).reshape(b, v * n, -1)
        x = fused
        for blk in self.transformer_layers:
            x = blk(x)
        logits = self.dpt_decoder(x.reshape(b * v, n, -1), h, w)
        return {"fused": fused, "tokens": x,
                "logits": logits.reshape(b, v, 1, logits.shape[-2], logits.shape[-1])}


class CrossViewDynamicRegionPredictor(nn.Module):
    """model/cv_drp.CrossViewDynamicRegionPredictor: a holder for ``estimator``."""

    def __init__(self, cfg: SparConfig):
        super().__init__()
        self.patch_size = cfg.patch_size
        self.mask_threshold = cfg.mask_threshold
        self.estimator = CVDRPFusion(cfg.d, cfg.cv_drp_n_heads, cfg.cv_drp_n_layer, cfg.dino_width)

    def forward(self, dino, img, ray, h, w):
        return self.estimator(dino, img, ray, h, w)


# ============================================================================ SPAR
def _gather(x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """x [B, V, ...], idx [B, K] -> [B, K, ...] (official ``x[batch_idx, idx]``)."""
    bidx = torch.arange(x.shape[0], device=x.device)[:, None]
    return x[bidx, idx]


def _as_index(idx: Optional[IndexLike], b: int, device) -> torch.Tensor:
    if idx is None:
        return torch.zeros(b, 0, dtype=torch.long, device=device)
    t = torch.as_tensor(idx, dtype=torch.long, device=device)
    if t.dim() == 1:
        t = t[None].expand(b, -1)
    assert t.dim() == 2 and t.shape[0] == b
    return t.contiguous()


class SPAR(nn.Module):
    """SPAR with the official module names.

    Args:
        cfg: SparConfig (``config.tiny()``, ``config.full()``, ``config.get_config(path)``).
        dino: module with ``forward(images [B,3,H,W] in [0,1]) -> [B, H/16*W/16, D]``;
              None builds ``dino_v3.DinoV3(cfg.dino)``; False leaves it out (then
              ``forward`` needs ``dino_features``).
        lseg: module with ``forward(images [B,3,H,W] in [0,1]) -> [B, C_sem, H/2, W/2]``;
              None builds ``lseg.LSegEncoder(cfg.lseg)`` when cfg.use_lseg; False leaves it
              out (then ``forward`` needs ``lseg_features`` when cfg.use_lseg).
    """

    def __init__(self, cfg: SparConfig, dino: Any = None, lseg: Any = None):
        super().__init__()
        cfg.validate()
        self.cfg = cfg
        d = cfg.d
        ps = cfg.patch_size

        # Registration order follows the official __init__ (state_dict order).
        self.scene_code = nn.Parameter(torch.zeros(cfg.scene_tokens, d))
        nn.init.trunc_normal_(self.scene_code, std=0.02)
        self.cam_code = nn.Parameter(torch.zeros(cfg.pose_tokens, d))
        nn.init.trunc_normal_(self.cam_code, std=0.02)

        self.image_tokenizer = nn.Sequential(
            Patchify(ps), nn.Linear(cfg.image_channels * ps * ps, d, bias=False))
        self.pe_embedder = _mlp2(d, d, d) if cfg.input_with_pe else nn.Identity()
        self.temporal_pe_embedder = _mlp2(d, d, d) if cfg.input_with_pe else nn.Identity()

        self.transformer_encoder = self._stack(cfg.encoder_n_layer)
        self.transformer_encoder_geom = self._stack(cfg.encoder_geom_n_layer)
        self.decoder_ln = LayerNorm(d, bias=False)
        self.transformer_decoder = self._stack(cfg.decoder_n_layer)

        self.pose_predictor = PoseEstimator(cfg)

        self.target_pose_tokenizer = nn.Sequential(
            Patchify(ps), nn.Linear(cfg.ray_channels * ps * ps, d, bias=False))
        self.target_pose_tokenizer2 = nn.Sequential(
            Patchify(ps), nn.Linear(cfg.ray_channels * ps * ps, d, bias=False))
        self.mlp_fuse = nn.Sequential(
            LayerNorm(2 * d, bias=False), nn.Linear(2 * d, d), nn.SiLU(), nn.Linear(d, d))
        self.image_token_decoder = nn.Sequential(
            LayerNorm(d, bias=False), nn.Linear(d, ps * ps * 3, bias=False), nn.Sigmoid())
        self.view_type_embedding = nn.Embedding(2, d)

        for m in (self.image_tokenizer, self.pe_embedder, self.temporal_pe_embedder,
                  self.target_pose_tokenizer, self.target_pose_tokenizer2, self.mlp_fuse,
                  self.image_token_decoder):
            m.apply(_init_linear)
        nn.init.normal_(self.view_type_embedding.weight, std=0.02)

        self.cv_drp = CrossViewDynamicRegionPredictor(cfg)

        self.mask_token = nn.Parameter(torch.zeros(1, 1, d))
        nn.init.normal_(self.mask_token, std=0.02)
        # OFFICIAL: used only by input_masking_mode 'learnable_indicator', always in the keys.
        self.static_indicator = nn.Parameter(torch.zeros(1, 1, d))
        self.dynamic_indicator = nn.Parameter(torch.zeros(1, 1, d))
        nn.init.normal_(self.static_indicator, std=0.02)
        nn.init.normal_(self.dynamic_indicator, std=0.02)

        # semantic modules (official _init_semantic_modules; lseg_model first)
        if cfg.use_lseg:
            if lseg is None:
                from . import lseg as lseg_mod
                lseg = lseg_mod.LSegEncoder(cfg.lseg)
            if lseg is not False:
                self.lseg_model = lseg
                for p in self.lseg_model.parameters():
                    p.requires_grad_(False)
            else:
                self.lseg_model = None
            self.semantic_pool = nn.AvgPool2d(kernel_size=8, stride=8)
            self.semantic_proj = nn.Linear(cfg.semantic_dim + 6, d)
            self.target_pose_tokenizer_semantic = nn.Sequential(
                Patchify(ps), nn.Linear(cfg.ray_channels * ps * ps, d, bias=False))
            self.semantic_token_decoder = nn.Sequential(
                LayerNorm(d, bias=False),
                nn.Linear(d, 2 * d, bias=False), nn.GELU(),
                nn.Linear(2 * d, 4 * d, bias=False), nn.GELU(),
                nn.Linear(4 * d, ps * ps * cfg.semantic_hidden, bias=False))
            # OFFICIAL: nn.Upsample(scale_factor=0.5, mode='bilinear') then Conv2d 1x1 (bias).
            self.semantic_feature_expansion = nn.Sequential(
                nn.Upsample(scale_factor=0.5, mode="bilinear"),
                nn.Conv2d(cfg.semantic_hidden, cfg.semantic_dim, kernel_size=1, stride=1))
            for m in (self.semantic_proj, self.target_pose_tokenizer_semantic,
                      self.semantic_token_decoder, self.semantic_feature_expansion):
                m.apply(_init_linear)
        else:
            self.lseg_model = None

        if cfg.plucker_norm_mode == "learnable":
            self.log_plucker_scale = nn.Parameter(torch.zeros(1))

        # DINOv3: the official model gets ``_dino_v3`` assigned after construction
        # (train_spar.py), so its keys come last in a training checkpoint.
        if dino is None:
            from . import dino_v3 as dino_mod
            dino = dino_mod.DinoV3(cfg.dino)
        if dino is not False:
            self._dino_v3 = dino
            for p in self._dino_v3.parameters():
                p.requires_grad_(False)
        else:
            self._dino_v3 = None

        self.eval()  # BatchNorm in eval mode: running statistics

    # ------------------------------------------------------------------ building blocks
    def _stack(self, n_layers: int) -> nn.ModuleList:
        cfg = self.cfg
        layers = nn.ModuleList([spar_block(cfg.d, cfg.d_head, cfg.use_qk_norm)
                                for _ in range(n_layers)])
        # official special_init + depth_init (spar.yaml): std 0.02 / sqrt(2 (i+1))
        for i, layer in enumerate(layers):
            layer.apply(functools.partial(_init_linear, std=0.02 / math.sqrt(2 * (i + 1))))
        return layers

    @property
    def dtype(self) -> torch.dtype:
        return self.scene_code.dtype

    def add_spatial_temporal_pe(self, tok: torch.Tensor, b: int, v: int) -> Tuple[torch.Tensor, torch.Tensor]:
        """Official add_sptial_temporal_pe: tok [(b v), n, D] + pe_embedder(concat(2D code
        (D/2) of the patch, 1D code (D/2) of the view index in the sequence))."""
        cfg = self.cfg
        d = cfg.d
        n = cfg.tokens_per_view
        spatial = sincos_2d(d // 2, cfg.patches_h, cfg.patches_w, tok.dtype, tok.device)  # [n, D/2]
        temporal = sincos_1d(d // 2, torch.arange(v, device=tok.device), tok.dtype)          # [v, D/2]
        code = torch.cat([spatial[None].expand(v, n, d // 2),
                          temporal[:, None].expand(v, n, d // 2)], dim=-1)                   # [v, n, D]
        pe = self.pe_embedder(code)
        return tok + pe.repeat(b, 1, 1), code

    def camera_tokens(self, b: int, v: int, dtype, device) -> torch.Tensor:
        """Official get_camera_tokens: cam_code + temporal_pe_embedder(1D code (D) of the view
        index) -> [B, V, D]."""
        code = sincos_1d(self.cfg.d, torch.arange(v, device=device), dtype)
        tok = self.cam_code[0][None] + self.temporal_pe_embedder(code)
        return tok[None].expand(b, v, -1)

    def normalize_plucker(self, rays: torch.Tensor) -> torch.Tensor:
        """Official _normalize_plucker_rays, rays [B, V, 6, H, W]."""
        mode = self.cfg.plucker_norm_mode
        if mode == "none":
            return rays
        b = rays.shape[0]
        moment = rays[:, :, :3]
        if mode == "per_scene":
            scale = moment.abs().reshape(b, -1).max(dim=1)[0].clamp(min=1e-6).reshape(b, 1, 1, 1, 1)
        else:
            scale = torch.exp(self.log_plucker_scale)
        return torch.cat([moment / scale, rays[:, :, 3:]], dim=2)

    def gate(self, tokens: torch.Tensor, dynamic_patch: torch.Tensor, v: int, gh: int, gw: int
             ) -> torch.Tensor:
        """Input-token masking (official _apply_configurable_input_masking).

        tokens [B, v*gh*gw, D]; dynamic_patch [B, v*gh*gw]: the dynamic probability P_m
        average-pooled per token. soft_with_pe: tok*s + (mask_token + 2D code)*(1-s), s the
        static probability.

        Order of operations: the official code pools s = 1 - P_m and forms 1 - s again; with
        P_m ~ 0.01 this cancels in fp32 (relative error ~1e-5 on the mask weight). Here the
        pooled P_m itself is the mask weight and s = 1 - pool(P_m): identical in exact
        arithmetic, and free of that cancellation."""
        mode = self.cfg.input_masking_mode
        dyn = dynamic_patch.to(tokens.dtype).unsqueeze(-1)
        stat = 1.0 - dyn
        if mode == "soft_with_pe":
            pe = sincos_2d(tokens.shape[-1], gh, gw, tokens.dtype, tokens.device).repeat(v, 1)
            return tokens * stat + (self.mask_token + pe[None]) * dyn
        if mode == "zero_out":
            return tokens * stat
        if mode == "learnable_indicator":
            return tokens + stat * self.static_indicator + dyn * self.dynamic_indicator
        return tokens

    def run_cv_drp(self, dino: torch.Tensor, img: torch.Tensor, ray: torch.Tensor, mode: str
                   ) -> Dict[str, Any]:
        """Official _run_cv_drp_paired: dino/img/ray [B, V, n, D] of one subset (inputs or
        targets). Each pair (i, j) runs CV-DRP on 2 views; a view's logits are averaged over
        the pairs it is in, BEFORE the sigmoid."""
        cfg = self.cfg
        b, v, n, _ = dino.shape
        pairs = get_view_pairs(v, mode)
        buckets: List[List[torch.Tensor]] = [[] for _ in range(v)]
        fused, toks, plog = [], [], []
        for (i, j) in pairs:
            res = self.cv_drp(torch.stack([dino[:, i], dino[:, j]], 1),
                              torch.stack([img[:, i], img[:, j]], 1),
                              torch.stack([ray[:, i], ray[:, j]], 1),
                              cfg.patches_h, cfg.patches_w)
            fused.append(res["fused"])
            toks.append(res["tokens"])
            plog.append(res["logits"])
            buckets[i].append(res["logits"][:, 0:1])
            if i != j:
                buckets[j].append(res["logits"][:, 1:2])
        per_view = []
        for bk in buckets:
            if not bk:  # official: zeros (cannot happen with the official pairings)
                per_view.append(torch.zeros(b, 1, 1, cfg.image_height, cfg.image_width,
                                            dtype=dino.dtype, device=dino.device))
            elif len(bk) == 1:
                per_view.append(bk[0])
            else:
                per_view.append(torch.stack(bk, 0).mean(0))
        logits = torch.cat(per_view, dim=1)
        prob = torch.sigmoid(logits)
        return {"pairs": pairs, "logits": logits, "prob": prob,
                "binary": prob > cfg.mask_threshold,
                "pair_fused": torch.stack(fused, 0), "pair_tokens": torch.stack(toks, 0),
                "pair_logits": torch.stack(plog, 0)}

    def run_stack(self, layers: nn.ModuleList, x: torch.Tensor,
                  record: Optional[List[torch.Tensor]] = None) -> torch.Tensor:
        for blk in layers:
            x = blk(x)
            if record is not None:
                record.append(x)
        return x

    # ------------------------------------------------------------------ forward
    def forward(self, images: torch.Tensor, input_idx: IndexLike,
                target_idx: Optional[IndexLike] = None, *,
                render_c2w: Optional[torch.Tensor] = None,
                render_fxfycxcy: Optional[torch.Tensor] = None,
                dynamic_mask: Optional[torch.Tensor] = None,
                dino_features: Optional[torch.Tensor] = None,
                lseg_features: Optional[torch.Tensor] = None,
                semantic_queries: Optional[bool] = None,
                semantic_head: bool = True,
                render: bool = True,
                record_layers: bool = False,
                assume_static: bool = False) -> Dict[str, Any]:
        """Run SPAR on one ordered sequence of frames.

        Args:
            images: [B, V, 3, H, W] in [0, 1], ALL frames in capture order. The pose encoder
                runs over all of them; the view-index codes and the canonical view (V//2 for
                canonical 'middle') are positions in this sequence.
            input_idx: indices of the input (context) views, list or LongTensor [K] / [B, K].
            target_idx: indices of the target views (may be None / empty). Targets take part
                in pose estimation and get CV-DRP masks; they are rendered with their
                estimated cameras unless ``render_c2w`` is given.
            render_c2w, render_fxfycxcy: explicit cameras to render instead of the estimated
                target cameras (rendering mode): [B, R, 4, 4] c2w in the canonical frame of
                the estimated poses, and [B, R, 4] normalized intrinsics (fx/W, fy/H, cx/W,
                cy/H).
            dynamic_mask: [B, K, 1, H, W] P(dynamic) for the input views to use for gating
                instead of CV-DRP's (official mask_source 'gt'); CV-DRP still runs.
            dino_features: [B, V, n, D] precomputed DINOv3 patch tokens (skip the backbone).
            lseg_features: [B, K, C_sem, H/2, W/2] precomputed LSeg features of the inputs.
            semantic_queries: put semantic queries into the decoder (default:
                cfg.semantic_decoding, the official training/eval behaviour; the official
                SPAR.render_images_video renders RGB without them).
            semantic_head: run the semantic head (semantic_token_decoder and
                semantic_feature_expansion) on the decoded semantic tokens; False skips it
                (the semantic queries still take part in the decoder, so RGB is unchanged)
                and leaves out semantic_out_tokens / semantic_hidden / semantic_features.
            render: False stops after the scene tokens (no render_* / decoder / rgb / semantic
                entries); ``render(out, ...)`` renders from that dict later, e.g. along cameras
                derived from the estimated ones.
            assume_static: the scene is declared static: DINOv3 and CV-DRP do not run (no
                ``dino`` / ``cv_drp_*`` entries) and no input token is gated (the engine's
                ``--assume-static``; the same as gating with P(dynamic) = 0 everywhere).
            record_layers: also return every layer's output of the three stacks under
                ``layers`` = {"transformer_encoder": [...], "transformer_encoder_geom": [...],
                "transformer_decoder": [...]}.

        Returns a dict (B batch, V all views, K inputs, T targets, R rendered views,
        n = tokens per view, S scene tokens, D width):
            input_idx [B,K], target_idx [B,T]
            img_tokens_raw [B,V,n,D]   image_tokenizer(2*img-1)
            pe_code [V,n,D]            sin-cos code fed to pe_embedder
            img_tokens [B,V,n,D]       + pe_embedder(code)
            cam_tokens_in [B,V,D]      cam_code + temporal_pe_embedder(code)
            pose_encoder_out [B,V+V*n,D]
            cam_tokens [B,V,D]         camera tokens after the pose encoder
            cam_info [B,V,13]          raw pose head output (6D rot, t, fx, fy, cx, cy)
            c2w [B,V,4,4], fxfycxcy [B,V,4] (normalized intrinsics)
            plucker [B,V,6,H,W]
            ray_tokens [B,V,n,D]       target_pose_tokenizer over all views
            dino [B,V,n,D]
            cv_drp_input / cv_drp_target: dict(pairs, logits [B,*,1,H,W], prob, binary (bool,
                prob > mask_threshold, the evaluation's motion mask),
                pair_fused [P,B,2n,D], pair_tokens [P,B,2n,D], pair_logits [P,B,2,1,H,W])
            dynamic_mask_input [B,K,1,H,W]  the mask used for gating
            dynamic_patch [B,K*n], static_patch [B,K*n]
            fused_tokens [B,K*n,D]     mlp_fuse(concat(img tok, ray tok)) + view_type[0]
            gated_tokens [B,K*n,D]
            lseg_features [B,K,C,H/2,W/2], semantic_in [B*K,C+6,H/16,W/16] (pooled)
            semantic_tokens [B,K*ns,D] semantic_proj + view_type[0]
            dynamic_patch_sem [B,K*ns], gated_semantic_tokens [B,K*ns,D]
            scene_encoder_in [B,S+K*n+K*ns,D], scene_encoder_out, scene_tokens [B,S,D]
            render_c2w [B,R,4,4], render_fxfycxcy [B,R,4], render_plucker [B,R,6,H,W]
            rgb_queries [B,R,n,D], semantic_queries [B,R,n,D] (or None)
            decoder_in [B*R,L,D] (after decoder_ln), decoder_out [B*R,L,D]
            rgb_tokens [B*R,n,D], rgb [B,R,3,H,W]
            semantic_out_tokens [B*R,n,D], semantic_hidden [B,R,64,H,W],
            semantic_features [B,R,C_sem,H/2,W/2]
        """
        cfg = self.cfg
        dt = self.dtype
        dev = self.scene_code.device
        images = images.to(device=dev, dtype=dt)
        b, v, c, h, w = images.shape
        assert (h, w) == (cfg.image_height, cfg.image_width), "image size differs from config"
        n = cfg.tokens_per_view
        d = cfg.d
        in_idx = _as_index(input_idx, b, dev)
        tg_idx = _as_index(target_idx, b, dev)
        k_in, k_tg = in_idx.shape[1], tg_idx.shape[1]
        assert k_in >= 1
        out: Dict[str, Any] = {"input_idx": in_idx, "target_idx": tg_idx}
        rec: Dict[str, Optional[List[torch.Tensor]]] = {
            name: ([] if record_layers else None)
            for name in ("transformer_encoder", "transformer_encoder_geom", "transformer_decoder")}
        if record_layers:
            out["layers"] = rec

        # ---- image tokens with spatial-temporal codes (all views)
        tok = self.image_tokenizer(images * 2.0 - 1.0)                   # [(b v), n, D]
        out["img_tokens_raw"] = tok.reshape(b, v, n, d)
        if cfg.input_with_pe:
            tok, code = self.add_spatial_temporal_pe(tok, b, v)
            out["pe_code"] = code
        img_tokens = tok.reshape(b, v, n, d)
        out["img_tokens"] = img_tokens

        # ---- pose encoder over [V camera tokens, V*n image tokens]
        cam = self.camera_tokens(b, v, dt, dev)
        out["cam_tokens_in"] = cam
        enc = self.run_stack(self.transformer_encoder,
                             torch.cat([cam, img_tokens.reshape(b, v * n, d)], dim=1),
                             rec["transformer_encoder"])
        out["pose_encoder_out"] = enc
        cam_out = enc[:, :v]
        out["cam_tokens"] = cam_out
        cam_info = self.pose_predictor(cam_out)                          # [B, V, 13]
        out["cam_info"] = cam_info
        c2w, fxfycxcy = cam_info_to_se3(cam_info.reshape(b * v, -1))
        out["c2w"] = c2w.reshape(b, v, 4, 4)
        out["fxfycxcy"] = fxfycxcy.reshape(b, v, 4)

        # ---- Plücker rays and ray tokens
        rays = plucker_rays(c2w, fxfycxcy, h, w, normalized=True).reshape(b, v, 6, h, w)
        rays = self.normalize_plucker(rays)
        out["plucker"] = rays
        ray_tokens = self.target_pose_tokenizer(rays).reshape(b, v, n, d)
        out["ray_tokens"] = ray_tokens

        # ---- DINOv3 features and CV-DRP, left out for a scene declared static
        if assume_static:
            out["cv_drp_input"] = out["cv_drp_target"] = None
        else:
            if dino_features is None:
                if self._dino_v3 is None:
                    raise ValueError("no DINOv3 module and no dino_features given")
                dino_features = self._dino_v3(images.reshape(b * v, c, h, w))
            dino_features = dino_features.to(dt).reshape(b, v, n, -1)
            assert dino_features.shape[-1] == d, "DINO width must equal D"
            out["dino"] = dino_features

            # CV-DRP (inputs paired (i, i+1), targets (i, T-1-i)); image tokens WITH codes,
            # ray tokens from target_pose_tokenizer for inputs and targets alike.
            out["cv_drp_input"] = self.run_cv_drp(_gather(dino_features, in_idx),
                                                  _gather(img_tokens, in_idx),
                                                  _gather(ray_tokens, in_idx), "input")
            if k_tg > 0:
                out["cv_drp_target"] = self.run_cv_drp(_gather(dino_features, tg_idx),
                                                       _gather(img_tokens, tg_idx),
                                                       _gather(ray_tokens, tg_idx), "target")
            else:
                out["cv_drp_target"] = None

        # ---- gating of the input tokens (none for a static scene)
        dyn = dyn_patch = None
        if dynamic_mask is not None:
            dyn = dynamic_mask.to(dt)
        elif not assume_static:
            dyn = out["cv_drp_input"]["prob"]
        if dyn is not None:
            out["dynamic_mask_input"] = dyn
            ps = cfg.patch_size
            dyn_patch = F.avg_pool2d(dyn.reshape(b * k_in, 1, h, w), kernel_size=ps, stride=ps)
            dyn_patch = dyn_patch.reshape(b, k_in * n)
            out["dynamic_patch"] = dyn_patch
            out["static_patch"] = 1.0 - dyn_patch

        fused = self.mlp_fuse(torch.cat([_gather(img_tokens, in_idx).reshape(b, k_in * n, d),
                                         _gather(ray_tokens, in_idx).reshape(b, k_in * n, d)],
                                        dim=-1))
        fused = fused + self.view_type_embedding.weight[0]
        out["fused_tokens"] = fused
        gated = fused if dyn_patch is None else self.gate(fused, dyn_patch, k_in, cfg.patches_h,
                                                          cfg.patches_w)
        out["gated_tokens"] = gated

        # ---- semantic input tokens
        sem_gated = None
        if cfg.use_lseg:
            if lseg_features is None:
                if self.lseg_model is None:
                    raise ValueError("no LSeg module and no lseg_features given")
                # OFFICIAL: LSeg sees the input images in [0, 1] as they are
                # (extract_lseg_features(input.image)); any normalization is the backbone's.
                lseg_features = self.lseg_model(_gather(images, in_idx).reshape(b * k_in, c, h, w))
            lseg_features = lseg_features.to(dt).reshape(b * k_in, cfg.semantic_dim, h // 2, w // 2)
            out["lseg_features"] = lseg_features.reshape(b, k_in, cfg.semantic_dim, h // 2, w // 2)
            rays_half = F.interpolate(_gather(rays, in_idx).reshape(b * k_in, 6, h, w),
                                      scale_factor=0.5, mode="bilinear", align_corners=False)
            pooled = self.semantic_pool(torch.cat([lseg_features, rays_half], dim=1))
            out["semantic_in"] = pooled
            hs, ws = h // 16, w // 16
            sem = pooled.reshape(b, k_in, -1, hs * ws).permute(0, 1, 3, 2).reshape(b, k_in * hs * ws, -1)
            sem = self.semantic_proj(sem) + self.view_type_embedding.weight[0]
            out["semantic_tokens"] = sem
            # OFFICIAL: pooled with a fixed 16x16 kernel (h_sem = H // 16), not patch_size.
            if dyn is None:
                sem_gated = sem
            else:
                dyn_sem = F.avg_pool2d(dyn.reshape(b * k_in, 1, h, w), kernel_size=16, stride=16)
                dyn_sem = dyn_sem.reshape(b, k_in * hs * ws)
                out["dynamic_patch_sem"] = dyn_sem
                sem_gated = self.gate(sem, dyn_sem, k_in, hs, ws)
            out["gated_semantic_tokens"] = sem_gated

        # ---- scene encoder over [scene_code, gated image tokens, gated semantic tokens]
        parts = [self.scene_code[None].expand(b, -1, -1), gated]
        if sem_gated is not None:
            parts.append(sem_gated)
        scene_in = torch.cat(parts, dim=1)
        out["scene_encoder_in"] = scene_in
        scene_out = self.run_stack(self.transformer_encoder_geom, scene_in,
                                   rec["transformer_encoder_geom"])
        out["scene_encoder_out"] = scene_out
        scene = scene_out[:, :cfg.scene_tokens]
        out["scene_tokens"] = scene

        if not render:
            return out
        return self.render(out, render_c2w, render_fxfycxcy, semantic_queries=semantic_queries,
                           semantic_head=semantic_head, record=rec["transformer_decoder"])

    def render(self, out: Dict[str, Any], render_c2w: Optional[torch.Tensor] = None,
               render_fxfycxcy: Optional[torch.Tensor] = None, *,
               semantic_queries: Optional[bool] = None, semantic_head: bool = True,
               record: Optional[List[torch.Tensor]] = None) -> Dict[str, Any]:
        """The rendering part of ``forward`` (decoder and heads), on the output dict of a
        ``forward(..., render=False)`` call: renders the target views with their estimated
        cameras, or the cameras ``render_c2w`` / ``render_fxfycxcy`` ([B,R,4,4] OpenCV c2w in
        the canonical frame, [B,R,4] normalized intrinsics). Adds the render_* / decoder /
        rgb / semantic entries to ``out`` (overwriting those of an earlier render) and
        returns it. ``record``: list to append each decoder layer's output to."""
        cfg = self.cfg
        dt = self.dtype
        dev = self.scene_code.device
        b, v = out["c2w"].shape[:2]
        h, w = cfg.image_height, cfg.image_width
        n, d, ps = cfg.tokens_per_view, cfg.d, cfg.patch_size
        tg_idx = out["target_idx"]
        k_tg = tg_idx.shape[1]
        rays = out["plucker"]
        scene = out["scene_tokens"]
        for key in ("rgb_queries", "semantic_queries", "decoder_in", "decoder_out", "rgb_tokens",
                    "rgb", "semantic_out_tokens", "semantic_hidden", "semantic_features"):
            out.pop(key, None)

        # ---- cameras to render
        if render_c2w is not None:
            assert render_fxfycxcy is not None
            r_c2w = render_c2w.to(device=dev, dtype=dt)
            r_k = render_fxfycxcy.to(device=dev, dtype=dt)
            r = r_c2w.shape[1]
            r_rays = plucker_rays(r_c2w.reshape(b * r, 4, 4), r_k.reshape(b * r, 4), h, w,
                                  normalized=True).reshape(b, r, 6, h, w)
            r_rays = self.normalize_plucker(r_rays)
        else:
            r = k_tg
            r_c2w = _gather(out["c2w"], tg_idx)
            r_k = _gather(out["fxfycxcy"], tg_idx)
            r_rays = _gather(rays, tg_idx)
        out["render_c2w"], out["render_fxfycxcy"], out["render_plucker"] = r_c2w, r_k, r_rays
        if r == 0:
            return out

        # ---- decoder per rendered view: [RGB queries, semantic queries, scene tokens]
        use_sem_q = cfg.semantic_decoding if semantic_queries is None else bool(semantic_queries)
        use_sem_q = use_sem_q and cfg.use_lseg
        rgb_q = self.target_pose_tokenizer2(r_rays) + self.view_type_embedding.weight[1]
        out["rgb_queries"] = rgb_q.reshape(b, r, n, d)
        seq = [rgb_q]
        sem_q = None
        if use_sem_q:
            sem_q = self.target_pose_tokenizer_semantic(r_rays) + self.view_type_embedding.weight[1]
            seq.append(sem_q)
        out["semantic_queries"] = None if sem_q is None else sem_q.reshape(b, r, n, d)
        seq.append(scene[:, None].expand(b, r, -1, -1).reshape(b * r, cfg.scene_tokens, d))
        dec_in = self.decoder_ln(torch.cat(seq, dim=1))
        out["decoder_in"] = dec_in
        dec = self.run_stack(self.transformer_decoder, dec_in, record)
        out["decoder_out"] = dec

        rgb_tok = dec[:, :n]
        out["rgb_tokens"] = rgb_tok
        out["rgb"] = unpatchify(self.image_token_decoder(rgb_tok), b, r,
                                cfg.patches_h, cfg.patches_w, ps, 3)
        if sem_q is not None and semantic_head:
            sem_tok = dec[:, n:2 * n]
            out["semantic_out_tokens"] = sem_tok
            hid = unpatchify(self.semantic_token_decoder(sem_tok), b, r,
                             cfg.patches_h, cfg.patches_w, ps, cfg.semantic_hidden)
            out["semantic_hidden"] = hid
            feat = self.semantic_feature_expansion(hid.reshape(b * r, cfg.semantic_hidden, h, w))
            out["semantic_features"] = feat.reshape(b, r, cfg.semantic_dim, h // 2, w // 2)
        return out


# ============================================================================ checkpoints
def spar_own_state_dict(model: SPAR) -> Dict[str, torch.Tensor]:
    """state_dict without the backbones (``_dino_v3.*``, ``lseg_model.*``)."""
    return {k: v for k, v in model.state_dict().items()
            if not (k.startswith("_dino_v3.") or k.startswith("lseg_model."))}


@torch.no_grad()
def perturb_parameters(model: nn.Module, seed: int, bias_std: float = 0.1,
                       norm_std: float = 0.1, pose_head_std: float = 0.03,
                       layerscale: Tuple[float, float] = (0.05, 0.5),
                       skip_prefixes: Tuple[str, ...] = ("_dino_v3", "lseg_model")) -> None:
    """Make the weights informative for tests: the official init has zero biases, BatchNorm
    statistics (0, 1), LayerScale 1e-5, pose heads of std 1e-3 and a CV-DRP head bias of -4.6,
    which hide dropped biases, statistics and scales.

    * every bias: N(0, bias_std), except the CV-DRP head bias: N(-1, 0.5) so P(dynamic)
      spans (0, 1) instead of ~0.01;
    * every norm weight (LayerNorm, RMSNorm, BatchNorm): 1 + N(0, norm_std);
    * BatchNorm running_mean N(0, 0.2), running_var U(0.5, 2), num_batches_tracked 1000;
    * LayerScale gammas (names ending in ``gamma`` or ``ls1``/``ls2`` params): U(layerscale);
    * pose heads' weights N(0, pose_head_std), so that poses differ from identity;
    * semantic_feature_expansion conv bias included in "every bias".
    Modules under ``skip_prefixes`` (the backbones, which randomize themselves) are left alone."""
    g = torch.Generator().manual_seed(seed)

    def rn(t, std, mean=0.0):
        return (torch.randn(t.shape, generator=g, dtype=torch.float64) * std + mean).to(t.dtype)

    norm_types = (nn.LayerNorm, nn.BatchNorm2d, nn.GroupNorm)
    for mname, mod in model.named_modules():
        if any(mname == sp or mname.startswith(sp + ".") for sp in skip_prefixes):
            continue
        is_norm = isinstance(mod, norm_types) or type(mod).__name__ in ("LayerNorm", "RMSNorm")
        for pname, p in mod.named_parameters(recurse=False):
            full = f"{mname}.{pname}" if mname else pname
            if pname == "bias":
                if full.endswith("dpt_decoder.head.bias"):
                    p.copy_(rn(p, 0.5, -1.0))
                else:
                    p.copy_(rn(p, bias_std))
            elif is_norm and pname == "weight":
                p.copy_(1.0 + rn(p, norm_std))
            elif pname == "gamma" or (p.dim() == 1 and mname.split(".")[-1] in ("ls1", "ls2")):
                lo, hi = layerscale
                u = torch.rand(p.shape, generator=g, dtype=torch.float64)
                p.copy_((lo + (hi - lo) * u).to(p.dtype))
            elif ("pose_predictor.rel_head" in full or "pose_predictor.canonical_k_head" in full) \
                    and pname == "weight":
                p.copy_(rn(p, pose_head_std))
        if isinstance(mod, nn.BatchNorm2d):
            mod.running_mean.copy_(rn(mod.running_mean, 0.2))
            u = torch.rand(mod.running_var.shape, generator=g, dtype=torch.float64)
            mod.running_var.copy_((0.5 + 1.5 * u).to(mod.running_var.dtype))
            mod.num_batches_tracked.fill_(1000)


def _cosine_with_warmup(step: int, warmup: int, total: int, num_cycles: float = 0.5) -> float:
    # transformers.get_cosine_schedule_with_warmup's lambda
    if step < warmup:
        return float(step) / float(max(1, warmup))
    progress = float(step - warmup) / float(max(1, total - warmup))
    return max(0.0, 0.5 * (1.0 + math.cos(math.pi * float(num_cycles) * 2.0 * progress)))


def _build_backbone(cls, sub_cfg, seed: int, perturb: bool):
    try:
        return cls(sub_cfg, seed=seed, perturb=perturb)
    except TypeError:  # a backbone class without seed/perturb arguments
        torch.manual_seed(seed)
        return cls(sub_cfg)


def make_checkpoint(cfg: SparConfig, seed: int = 0, *, perturb: bool = False,
                    dino: Any = None, lseg: Any = None, step: int = 2000,
                    optimizer_state: bool = True, lr: float = 2e-4, weight_decay: float = 0.05,
                    betas: Tuple[float, float] = (0.9, 0.95), warmup: int = 3000,
                    train_steps: int = 20000, backbone_init: bool = True) -> Dict[str, Any]:
    """What the official training saves (train_spar.save_checkpoint):
    ``{"model": state_dict, "optimizer": AdamW state_dict, "lr_scheduler": LambdaLR
    state_dict, "fwdbwd_pass_step": step, "param_update_step": step}``.

    Weights: the official initialization from ``seed`` (optionally ``perturb``ed, see
    perturb_parameters). The model state_dict holds SPAR's own tensors, ``lseg_model.*``
    (when cfg.use_lseg; the official SPAR registers its frozen LSeg) and ``_dino_v3.*`` (set by
    train_spar.py), fp32, BatchNorm ``num_batches_tracked`` int64. ``dino``/``lseg`` as in
    SPAR(): None builds the backbone modules, False leaves them out, a module is used as is.
    Not included: the VGG19 of the perceptual loss (``spar_loss_computer._perceptual_loss.*``,
    created lazily at the first training step and never needed for inference).

    The optimizer follows utils/training_utils.create_optimizer: AdamW(foreach) with groups
    'default' (params with dim > 1, weight decay) and 'default_nodecay' (1-D params) over the
    trainable parameters (frozen backbones excluded); with ``optimizer_state`` each parameter
    gets synthetic Adam moments at ``step``. The scheduler is the cosine-with-warmup LambdaLR
    stepped ``step`` times.

    ``backbone_init=False`` builds the backbones without torch.nn.init's initial values, which
    their own seeded randomization overwrites anyway (a full-size model: 6.6 s saved). SPAR's
    own modules then draw theirs from a different point of the global generator, so the
    weights differ from the default's: for callers that need valid fixed-seed weights, not
    these particular ones (the full-size test fixture, made again on every build)."""
    from .backbones import no_initial_values
    torch.manual_seed(seed)
    skip = contextlib.nullcontext() if backbone_init else no_initial_values()
    with skip:
        if dino is None:
            from . import dino_v3 as dino_mod
            dino = _build_backbone(dino_mod.DinoV3, cfg.dino, seed + 11, perturb)
        if lseg is None and cfg.use_lseg:
            from . import lseg as lseg_mod
            lseg = _build_backbone(lseg_mod.LSegEncoder, cfg.lseg, seed + 12, perturb)
    model = SPAR(cfg, dino=dino, lseg=lseg)
    if perturb:
        perturb_parameters(model, seed + 1)
    model = model.float()

    named = [(k, p) for k, p in model.named_parameters() if p.requires_grad]
    decay = [p for _, p in named if p.dim() != 1]
    nodecay = [p for _, p in named if p.dim() == 1]
    groups = [{"name": "default", "params": decay, "weight_decay": weight_decay, "lr": lr},
              {"name": "default_nodecay", "params": nodecay, "weight_decay": 0.0, "lr": lr}]
    try:
        opt = torch.optim.AdamW(groups, lr=lr, betas=betas, foreach=True)
    except TypeError:  # pragma: no cover - very old torch
        opt = torch.optim.AdamW(groups, lr=lr, betas=betas)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, functools.partial(_cosine_with_warmup, warmup=warmup, total=train_steps))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(step):
            sched.step()
    if optimizer_state:
        g = torch.Generator().manual_seed(seed + 2)
        for _, p in named:
            opt.state[p] = {
                "step": torch.tensor(float(step)),
                "exp_avg": (torch.randn(p.shape, generator=g) * 1e-4).to(p.dtype),
                "exp_avg_sq": (torch.rand(p.shape, generator=g) * 1e-8).to(p.dtype),
            }
    return {
        "model": model.state_dict(),
        "optimizer": opt.state_dict(),
        "lr_scheduler": sched.state_dict(),
        "fwdbwd_pass_step": step,
        "param_update_step": step,
    }


def load_spar(cfg: SparConfig, state_dict: Dict[str, torch.Tensor], dino: Any = None,
              lseg: Any = None, strict: bool = True) -> SPAR:
    """Build SPAR and load a state_dict; unlike the official load_ckpt, a missing or
    mismatched tensor is an error (strict)."""
    model = SPAR(cfg, dino=dino, lseg=lseg)
    res = model.load_state_dict(state_dict, strict=strict)
    if not strict and (res.missing_keys or res.unexpected_keys):
        own_missing = [k for k in res.missing_keys
                       if not (k.startswith("_dino_v3.") or k.startswith("lseg_model."))]
        if own_missing:
            raise KeyError(f"missing SPAR tensors: {own_missing[:10]}")
    return model.eval()
