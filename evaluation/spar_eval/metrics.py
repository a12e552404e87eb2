"""Metrics of the evaluation protocol (PROTOCOL.md), as pure numpy float64 functions.

Every function takes one view (or one count matrix) and returns plain numbers, so the runner
only accumulates. Images are [H, W, 3] in [0, 1]; masks are bool [H, W]. A per-view metric
that the protocol skips (no static pixel, no valid static centre) returns None.
"""

from typing import Dict, Optional, Tuple

import numpy as np

SSIM_SIZE = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2
SSIM_HALF = SSIM_SIZE // 2          # 5: valid centres are 5 .. H-6


# ============================================================================ RGB
def psnr_static(render: np.ndarray, gt: np.ndarray, static: np.ndarray) -> Optional[float]:
    """PSNR over the static pixels: mse = sum over static pixels and RGB / (3 |S|)."""
    render = np.asarray(render, np.float64)
    gt = np.asarray(gt, np.float64)
    static = np.asarray(static, bool)
    n = int(static.sum())
    if n == 0:
        return None
    d = render[static] - gt[static]            # [n, 3]
    mse = float(np.sum(d * d)) / (3.0 * n)
    if mse == 0.0:
        return float("inf")                    # identical images; cannot happen with a model
    return 10.0 * np.log10(1.0 / mse)


# ============================================================================ baselines
def nearest_input(target: int, inputs) -> int:
    """The input frame nearest to `target` in sequence position; ties: the earlier one."""
    return min(inputs, key=lambda i: (abs(i - target), i))


def mean_colour_image(frames, shape) -> np.ndarray:
    """[H, W, 3]: every pixel the per-channel mean of all pixels of `frames` ([H, W, 3] each)."""
    mean = np.mean(np.stack([np.asarray(f, np.float64) for f in frames]).reshape(-1, 3), axis=0)
    return np.broadcast_to(mean, shape).copy()


def gaussian_window(size: int = SSIM_SIZE, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """The 1-D Gaussian whose outer product is the 2-D window. Normalizing the 1-D weights
    to sum 1 makes the 2-D weights sum to 1 too (the sum of an outer product is the product
    of the sums), so the 2-D window is exactly the protocol's normalized window."""
    x = np.arange(size, dtype=np.float64) - (size - 1) / 2.0
    g = np.exp(-(x * x) / (2.0 * sigma * sigma))
    return g / g.sum()


def _filter_valid(img: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Weighted window sums at the valid centres only (no padding): [H, W] -> [H-10, W-10].
    Separable: rows then columns (the 2-D weight is g[dy] * g[dx])."""
    s = len(g)
    rows = np.lib.stride_tricks.sliding_window_view(img, s, axis=1) @ g     # [H, W-10]
    return np.lib.stride_tricks.sliding_window_view(rows, s, axis=0) @ g    # [H-10, W-10]


def ssim_map(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """SSIM of one channel at the valid centres: [H, W] -> [H-10, W-10]; entry (i, j) is the
    centre (i + 5, j + 5)."""
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    g = gaussian_window()
    mx, my = _filter_valid(x, g), _filter_valid(y, g)
    vx = _filter_valid(x * x, g) - mx * mx
    vy = _filter_valid(y * y, g) - my * my
    cxy = _filter_valid(x * y, g) - mx * my
    num = (2.0 * mx * my + SSIM_C1) * (2.0 * cxy + SSIM_C2)
    den = (mx * mx + my * my + SSIM_C1) * (vx + vy + SSIM_C2)
    return num / den


def ssim_static(render: np.ndarray, gt: np.ndarray, static: np.ndarray) -> Optional[float]:
    """Mean SSIM over the 3 channels and the valid centres whose centre pixel is static."""
    render = np.asarray(render, np.float64)
    gt = np.asarray(gt, np.float64)
    h, w = static.shape
    if h < SSIM_SIZE or w < SSIM_SIZE:
        return None
    keep = np.asarray(static, bool)[SSIM_HALF:h - SSIM_HALF, SSIM_HALF:w - SSIM_HALF]
    n = int(keep.sum())
    if n == 0:
        return None
    total = 0.0
    for c in range(3):
        total += float(ssim_map(render[..., c], gt[..., c])[keep].sum())
    return total / (3.0 * n)


# ============================================================================ motion masks
def mask_counts(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """[TP, FP, FN, TN] (int64) of a predicted dynamic mask against the ground truth."""
    pred = np.asarray(pred, bool)
    gt = np.asarray(gt, bool)
    tp = int(np.sum(pred & gt))
    fp = int(np.sum(pred & ~gt))
    fn = int(np.sum(~pred & gt))
    tn = int(np.sum(~pred & ~gt))
    return np.array([tp, fp, fn, tn], np.int64)


def _ratio(a: int, b: int) -> Optional[float]:
    # 0/0 (e.g. no dynamic pixel anywhere and none predicted) is undefined: null, not 0 or 1
    return None if b == 0 else a / b


def mask_scores(counts: np.ndarray) -> Dict[str, Optional[float]]:
    """mIoU (mean of dynamic and static IoU), IoU_dyn and recall from accumulated counts."""
    tp, fp, fn, tn = (int(v) for v in counts)
    iou_dyn = _ratio(tp, tp + fp + fn)
    iou_static = _ratio(tn, tn + fp + fn)
    miou = None if iou_dyn is None or iou_static is None else (iou_dyn + iou_static) / 2.0
    return {"mask_miou": miou, "mask_iou_dynamic": iou_dyn, "mask_recall": _ratio(tp, tp + fn)}


# ============================================================================ semantics
def semantic_targets(classes: np.ndarray, static: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """(evaluated [H, W] bool, ground truth class [H, W]) of one view, at its full size (the
    label maps are made there, in the official order): every static pixel counts."""
    return np.asarray(static, bool), np.asarray(classes).astype(np.int64)


def confusion(pred: np.ndarray, gt: np.ndarray, evaluated: np.ndarray, n_classes: int
              ) -> np.ndarray:
    """[n, n] int64 confusion matrix (rows ground truth, columns prediction) of one view."""
    p = np.asarray(pred, np.int64)[evaluated]
    g = np.asarray(gt, np.int64)[evaluated]
    if p.size and (p.min() < 0 or p.max() >= n_classes or g.min() < 0 or g.max() >= n_classes):
        raise ValueError("class id outside 0 .. n_classes-1")
    return np.bincount(g * n_classes + p, minlength=n_classes * n_classes).reshape(
        n_classes, n_classes).astype(np.int64)


def semantic_scores(conf: np.ndarray) -> Dict[str, Optional[float]]:
    """mIoU over the classes with a ground-truth pixel, and pixel accuracy."""
    conf = np.asarray(conf, np.int64)
    total = int(conf.sum())
    if total == 0:
        return {"sem_miou": None, "sem_accuracy": None}
    tp = np.diag(conf).astype(np.float64)
    gt_count = conf.sum(axis=1)           # TP + FN
    pred_count = conf.sum(axis=0)         # TP + FP
    present = gt_count > 0
    iou = tp[present] / (gt_count[present] + pred_count[present] - tp[present])
    return {"sem_miou": float(iou.mean()), "sem_accuracy": float(tp.sum()) / total}
