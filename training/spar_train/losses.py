"""The paper's training losses (official model/spar_loss.py and the semantic part of
model/spar.py), without the perceptual term: that needs VGG19 weights we do not have.

  total = L_recon + 0.01 L_reg + 1.0 L_bce + 0.1 L_sem  (+ pose_weight L_pose, off by default)

L_recon: MSE weighted by the static probability 1 - P(dynamic) of the target pixels,
normalized by the weights (gradients reach CV-DRP through the weights, as in the official
code); copy-paste batches: plain MSE against the clean targets. L_reg: BCE of every view's
CV-DRP logits toward 0. L_bce: BCE of the logits of views with pasted objects against the
pasted masks. L_sem: cosine distance between rendered and teacher features, weighted the same
way (static probability bilinearly resized to H/2), plain on copy-paste batches.
dynamic_weighting=False is the ablation without the dynamic-region-aware loss (the official
apply_dynamic_*_loss_weighting = False: all-static weights)."""
import torch
import torch.nn.functional as F

L2_WEIGHT, REG_WEIGHT, BCE_WEIGHT, SEM_WEIGHT = 1.0, 0.01, 1.0, 0.1


def semantic_cosine(rendered, teacher, weight=None):
    """rendered, teacher [N, C, h, w]; weight [N, h, w] or None."""
    r = F.normalize(rendered, dim=1)
    t = F.normalize(teacher, dim=1)
    dist = 1.0 - F.cosine_similarity(r, t, dim=1, eps=1e-6)
    if weight is None:
        return dist.mean()
    return (dist * weight).sum() / (weight.sum() + 1e-8)


def camera_loss(c2w: torch.Tensor, fxfycxcy: torch.Tensor, true_c2w: torch.Tensor,
                true_fxfycxcy: torch.Tensor) -> torch.Tensor:
    """Supervision of the pose estimator by the generator's cameras (not in the paper's
    self-supervised recipe; the official config's pose_loss_weight is 0 there). All [B, V, ...]
    in the canonical view's frame. Rotations: squared Frobenius distance; positions: compared
    after dividing each scene's by its mean distance from the canonical camera (the model's
    scale is its own); intrinsics: squared error of the normalized values."""
    l_rot = ((c2w[..., :3, :3] - true_c2w[..., :3, :3]) ** 2).sum((-1, -2)).mean()

    def unit_scale(t):  # [B, V, 3] / mean over V of |t|
        return t / t.norm(dim=-1).mean(dim=1, keepdim=True)[..., None].clamp(min=1e-6)

    l_pos = ((unit_scale(c2w[..., :3, 3]) - unit_scale(true_c2w[..., :3, 3])) ** 2).sum(-1).mean()
    l_k = ((fxfycxcy - true_fxfycxcy) ** 2).sum(-1).mean()
    return l_rot + l_pos + l_k


def spar_losses(out: dict, batch: dict, teacher_features: torch.Tensor,
                dynamic_weighting: bool = True, pose_weight: float = 0.0) -> dict:
    b, t = batch["targets"].shape
    tg = batch["targets"]
    ar = torch.arange(b, device=tg.device)[:, None]
    render = out["rgb"]                                   # [B, T, 3, H, W]
    h, w = render.shape[-2:]
    copy_paste = batch["kind"] == "copy-paste"
    target = batch["clean"][ar, tg] if copy_paste else batch["images"][ar, tg]
    tg_logits = out["cv_drp_target"]["logits"]            # [B, T, 1, H, W]
    in_logits = out["cv_drp_input"]["logits"]             # [B, K, 1, H, W]

    if copy_paste:
        l_recon = F.mse_loss(render, target)
        weight = None
    else:
        p_dyn = torch.sigmoid(tg_logits)
        if not dynamic_weighting:
            p_dyn = torch.zeros_like(p_dyn)
        e_s = 1.0 - p_dyn                                  # [B, T, 1, H, W]
        l_recon = ((render - target) ** 2 * e_s).sum() / (e_s.sum() * 3 + 1e-8)
        weight = F.interpolate(e_s.reshape(b * t, 1, h, w), size=(h // 2, w // 2),
                               mode="bilinear", align_corners=False).squeeze(1)

    all_logits = torch.cat([in_logits, tg_logits], dim=1)
    l_reg = F.binary_cross_entropy_with_logits(all_logits, torch.zeros_like(all_logits))

    l_bce = render.new_zeros(())
    if copy_paste:
        paste = torch.cat([batch["paste"][ar, batch["inputs"]], batch["paste"][ar, tg]], dim=1)
        has = paste.flatten(2).sum(-1) > 0                 # [B, V]
        if has.any():
            l_bce = F.binary_cross_entropy_with_logits(all_logits[has], paste[has])

    sem = out["semantic_features"]                        # [B, T, C, h, w]
    l_sem = semantic_cosine(sem.flatten(0, 1), teacher_features, weight)

    total = L2_WEIGHT * l_recon + REG_WEIGHT * l_reg + BCE_WEIGHT * l_bce + SEM_WEIGHT * l_sem
    l_pose = camera_loss(out["c2w"], out["fxfycxcy"], batch["c2w"].to(out["c2w"]),
                         batch["fxfycxcy"].to(out["c2w"])) if "c2w" in batch else render.new_zeros(())
    if pose_weight:
        total = total + pose_weight * l_pose
    with torch.no_grad():
        psnr = -10.0 * torch.log10(F.mse_loss(render, target).clamp(min=1e-10))
    return {"loss": total, "recon": l_recon.detach(), "reg": l_reg.detach(),
            "bce": l_bce.detach(), "sem": l_sem.detach(), "pose": l_pose.detach(), "psnr": psnr}
