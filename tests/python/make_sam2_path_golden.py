#!/usr/bin/python3
"""Goldens of tests/test_sam2_path.cpp: SAM2.1's image encoder and mask decoder
(spar_reference.sam2.image_encoder, mask_prompt, prompt_dense, mask_decoder) of a tiny variant
in float64 on float32 weights:

    OUT/config.json       the variant (Sam2Config.to_dict(), as a packed file's sam2_config)
    OUT/weights/<key>.npy every tensor of the path, f32, official keys
    OUT/images.npy        [2, 3, 48, 40] f32 in [0, 1] (view 1 is encoded)
    OUT/stage_<i>.npy     the trunk's 4 stage maps [H, W, C] f64
    OUT/image_embed.npy [64 * 64, d], feat_s0.npy [256 * 256, d / 8], feat_s1.npy [128 * 128, d / 4]
                          f64, channel-last tokens
    OUT/probs.npy         [2, 48, 40] f32 P(dynamic) (view 1's is the prompt)
    OUT/prompt.npy [256 * 256], dense.npy [64 * 64, d], tokens_out.npy [6, d],
    upscaled.npy [256 * 256, d / 8], low_res_logits.npy [256 * 256, 3], iou.npy [1, 3],
    chosen_logits.npy [256 * 256] f64
    OUT/refine/           spar_reference.sam2.refine_masks of 3 views: images.npy, probs.npy
                          [3, 48, 40] f32 (a blob; nothing dynamic; exactly 10 dynamic pixels,
                          the skip rule's edge), refined.npy [3, 48, 40] f64 0/1, logits.npy
                          [3, 48, 40] f64 (the chosen mask's at full size; 0 where skipped),
                          summary.json (per view: skipped, iou, chosen, dynamic pixels)

The variant crosses what the trunk's schedule does: 6 blocks over 4 stages with q pooling at
blocks 1, 2, 4, a global block on the 64x64 map (4096 tokens), windows 6 on 64x64 (padded to
66) pooled to 3 at the transition into stage 4, and windows of 3 on 32x32 (padded to 33)."""
import argparse
import json
import os

import numpy as np
import torch

from spar_convert.sam2_config import Sam2Config, used_tensors
from spar_reference import sam2

CONFIG = Sam2Config(name="tiny_test", embed_dim=8, num_heads=1, stages=[1, 1, 2, 2], global_att_blocks=[3],
                    window_spec=[8, 4, 6, 3], window_pos_embed_bkg_spatial_size=[7, 7], d_model=64,
                    backbone_channel_list=[64, 32, 16, 8]).validate()
# The same schedule with its global block on the last map, at 256x256 images instead of 1024:
# token maps of 64, 32, 16 and 8 a side (stage 3's windows of 6 and stage 4's of 3 still padded,
# the position tables still resized and tiled), a 16x16 image embedding and 64x64 mask logits,
# a sixteenth of the official size's work (SwiftShader's self-test refinement 33 s -> ~2 s).
# The whole refinement in requests, spar render / eval and the self-test model use it; the
# official 1024 and the 4096-token global attention keep their tests here (CONFIG).
QUICK_CONFIG = Sam2Config(name="tiny_quick", embed_dim=8, num_heads=1, stages=[1, 1, 1, 2], global_att_blocks=[4],
                          window_spec=[8, 4, 6, 3], window_pos_embed_bkg_spatial_size=[7, 7], d_model=64,
                          backbone_channel_list=[64, 32, 16, 8], image_size=256).validate()
VIEW = 1


def tokens(nchw: torch.Tensor) -> np.ndarray:
    """[1, C, H, W] -> [H * W, C] float64."""
    return np.ascontiguousarray(nchw[0].permute(1, 2, 0).reshape(-1, nchw.shape[1]).numpy())


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    os.makedirs(os.path.join(args.out, "weights"), exist_ok=True)
    sd = sam2.make_checkpoint(CONFIG, seed=21)["model"]
    used = {k: sd[k] for k in used_tensors(CONFIG)}
    for k, v in used.items():
        np.save(os.path.join(args.out, "weights", k + ".npy"), v.numpy())
    g = torch.Generator().manual_seed(4)
    images = torch.rand(2, 3, 48, 40, generator=g)
    np.save(os.path.join(args.out, "images.npy"), images.numpy())
    with open(os.path.join(args.out, "config.json"), "w") as f:
        json.dump(CONFIG.to_dict(), f)
    record = {}
    sd64 = sam2.as_dtype(sd, CONFIG, torch.float64)
    with torch.no_grad():
        out = sam2.image_encoder(sam2.preprocess(images[VIEW], torch.float64, CONFIG.image_size), sd64, CONFIG, record)
    for i in range(4):
        s = np.ascontiguousarray(record["sam2_trunk_%d" % i][0].permute(1, 2, 0).numpy())  # [H, W, C]
        np.save(os.path.join(args.out, "stage_%d.npy" % i), s)
    for k in ("image_embed", "feat_s0", "feat_s1"):
        np.save(os.path.join(args.out, k + ".npy"), tokens(out[k]))
    # the decoder, prompted by a blob with soft edges around 0.5 (48 x 40 -> 256 x 256)
    yy, xx = torch.meshgrid(torch.arange(48.0), torch.arange(40.0), indexing="ij")
    probs = torch.stack([torch.sigmoid(2.0 - ((yy - cy) ** 2 + (xx - cx) ** 2) / 40.0) for cy, cx in ((20, 12), (30, 25))])
    np.save(os.path.join(args.out, "probs.npy"), probs.numpy().astype(np.float32))
    with torch.no_grad():
        prompt = sam2.mask_prompt(probs[VIEW].to(torch.float32).to(torch.float64), torch.float64,
                                 CONFIG.mask_input_size())
        dense = sam2.prompt_dense(sd64, prompt)
        pe = sam2.dense_pe(sd64, out["image_embed"].shape[-1], torch.float64)
        rec = {}
        logits, iou = sam2.mask_decoder(sd64, out, dense, pe, rec)
    np.save(os.path.join(args.out, "prompt.npy"), prompt.reshape(-1).numpy())
    np.save(os.path.join(args.out, "dense.npy"), tokens(dense))
    np.save(os.path.join(args.out, "tokens_out.npy"), rec["sam2_tokens_out"][0].numpy())
    np.save(os.path.join(args.out, "upscaled.npy"), tokens(rec["sam2_upscaled"]))
    np.save(os.path.join(args.out, "low_res_logits.npy"), tokens(logits[None]))
    np.save(os.path.join(args.out, "iou.npy"), iou[None].numpy())
    chosen = int(torch.argmax(iou).item())
    np.save(os.path.join(args.out, "chosen_logits.npy"), logits[chosen].reshape(-1).numpy())
    refine(os.path.join(args.out, "refine"), sd, probs[0])


def refine(out, sd, blob):
    """The whole refinement of 3 views as SPAR runs it."""
    os.makedirs(out, exist_ok=True)
    g = torch.Generator().manual_seed(8)
    images = torch.rand(3, 3, 48, 40, generator=g)
    edge = torch.zeros(48 * 40)
    edge[100:110] = 0.9
    probs = torch.stack([blob, torch.full((48, 40), 0.2), edge.reshape(48, 40)]).to(torch.float32)
    np.save(os.path.join(out, "images.npy"), images.numpy())
    np.save(os.path.join(out, "probs.npy"), probs.numpy())
    results = sam2.refine_masks(sd, CONFIG, images, probs.to(torch.float64), torch.float64)
    refined, full, summary = [], [], []
    for v, r in enumerate(results):
        refined.append(r["refined"].numpy())
        if r["skipped"]:
            full.append(np.zeros((48, 40)))
        else:
            full.append(torch.nn.functional.interpolate(r["logits"][None, None], size=(48, 40), mode="bilinear",
                                                        align_corners=False)[0, 0].numpy())
        summary.append(dict(skipped=r["skipped"], dynamic_pixels=r["dynamic_pixels"], chosen=r["chosen"],
                            iou=None if r["iou"] is None else [float(x) for x in r["iou"]]))
    np.save(os.path.join(out, "refined.npy"), np.stack(refined))
    np.save(os.path.join(out, "logits.npy"), np.stack(full))
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump(summary, f)


if __name__ == "__main__":
    main()
