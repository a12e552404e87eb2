"""The semantic teacher of this small world.

Text side: CLIP's text transformer (the real architecture, vocabulary and BPE tokenizer) with
seeded weights: spar_reference's deterministic initialization, then the token embedding table
redrawn as N(0, 1) (at the default 0.02 every prompt's end-token output is nearly the same
vector; unit-scale word vectors let the name tokens matter). Of the seeds tried, the one whose
class-name embeddings are best separated (smallest largest pairwise cosine) is kept: the class
feature vectors are the embeddings of the class names, and the trained model's `--labels`
prompts go through this same encoder in the engine.

Image side: a small LSeg (the official architecture: ViT with hooks, DPT reassemble, RefineNet,
head) trained as LSeg is trained: cross-entropy over the logits 1/0.07 * cos(pixel feature,
class text embedding), per pixel at H/2. Frozen afterwards: SPAR's semantic input tokens and
its semantic loss targets come from it, as the official SPAR uses a frozen LSeg."""
import time

import numpy as np
import torch
import torch.nn.functional as F

from spar_reference.bpe import tokenize
from spar_reference.clip_text import CLIPTextEncoder, LSEG_LOGIT_SCALE
from spar_scenes import CLASS_NAMES

from .data import to_tensor


def text_encoder(cfg, bpe: str, seeds=range(64), log=print):
    ids = torch.as_tensor(tokenize(list(CLASS_NAMES), bpe, int(cfg.clip["context_length"])))
    best = None
    for seed in seeds:
        enc = CLIPTextEncoder(cfg.clip, seed=seed).float()
        g = torch.Generator().manual_seed(seed)
        with torch.no_grad():
            enc.token_embedding.weight.copy_(torch.randn(enc.token_embedding.weight.shape, generator=g))
            e = F.normalize(enc(ids), dim=1)
        cos = e @ e.T
        worst = (cos - 2 * torch.eye(len(e))).max().item()
        if best is None or worst < best[0]:
            best = (worst, seed, enc, e)
    worst, seed, enc, emb = best
    log(f"text encoder: seed {seed} of {len(list(seeds))}, largest cosine between class names "
        f"{worst:.3f}")
    return enc.eval(), emb, seed


def train_lseg(lseg, pool, class_emb: torch.Tensor, steps: int, batch: int, seed: int,
               lr: float = 1e-3, log=print, device="cpu"):
    """Trains ``lseg`` in place on random frames of the pool (dynamic frames: people and pets
    are classes too) and returns the final pixel accuracy on a held-back batch."""
    rng = np.random.default_rng([seed, 202])
    n, f = pool.rgb.shape[:2]
    params = [p for p in lseg.parameters()]
    for p in params:
        p.requires_grad_(True)
    opt = torch.optim.AdamW(params, lr=lr, betas=(0.9, 0.95), weight_decay=0.05)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps, pct_start=0.1)
    txt = class_emb.detach().to(device)
    lseg.train()
    t0 = time.time()

    def draw():
        s, i = rng.integers(n, size=batch), rng.integers(f, size=batch)
        dyn = rng.random(batch) < 0.5
        rgb = np.where(dyn[:, None, None, None], pool.rgb[s, i], pool.static_rgb[s, i])
        cls = np.where(dyn[:, None, None], pool.classes[s, i], pool.static_classes[s, i])
        # the label of a half-resolution pixel: its 2x2 block's top-left class
        return (to_tensor(rgb).to(device),
                torch.as_tensor(cls[:, ::2, ::2].astype(np.int64)).to(device))

    for step in range(steps):
        x, y = draw()
        feat = F.normalize(lseg(x), dim=1)
        logits = LSEG_LOGIT_SCALE * torch.einsum("bchw,kc->bkhw", feat, txt)
        loss = F.cross_entropy(logits, y)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        if (step + 1) % 25 == 0 or step + 1 == steps:
            acc = (logits.argmax(1) == y).float().mean().item()
            log(f"lseg teacher step {step + 1}/{steps}: loss {loss.item():.4f} pixel acc {acc:.3f} "
                f"({time.time() - t0:.0f} s)")
    lseg.eval()
    for p in params:
        p.requires_grad_(False)
    with torch.no_grad():
        x, y = draw()
        feat = F.normalize(lseg(x), dim=1)
        acc = (torch.einsum("bchw,kc->bkhw", feat, txt).argmax(1) == y).float().mean().item()
    return acc
