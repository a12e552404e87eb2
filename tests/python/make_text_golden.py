#!/usr/bin/python3
"""Goldens of the text side for tests/test_bpe_tokenizer.cpp and tests/test_clip_text.cpp,
made at test time by the PyTorch reference (converter/spar_reference):

    make_text_golden.py --bpe MERGES.txt.gz --prompts PROMPTS.json --out DIR
                        [--checkpoint CK.pt --config CFG.json]

PROMPTS.json is a JSON list of strings (UTF-8). Writes DIR/
    tokens.npy        int64 [P, 77]: bpe.tokenize(prompts) (truncate=True, as cli.py)
    text.json         per prompt: {"normalized": the cleaned, lower-cased text, "pieces": the
                      pre-tokens, "encoded": bpe ids without start/end tokens}
    embeddings.npy    float64 [P, E] (with --checkpoint): the checkpoint's CLIP text encoder,
                      built as cli.py build_text_encoder does, run in float64 on tokens.npy
"""
import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
CONVERTER = os.path.join(os.path.dirname(os.path.dirname(HERE)), "converter")
sys.path.insert(0, CONVERTER)

from spar_reference import bpe  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--bpe", required=True)
    ap.add_argument("--prompts", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--checkpoint")
    ap.add_argument("--config")
    a = ap.parse_args()
    with open(a.prompts, encoding="utf-8") as f:
        prompts = json.load(f)
    os.makedirs(a.out, exist_ok=True)

    tok = bpe.get_tokenizer(a.bpe)
    ids = bpe.tokenize(prompts, a.bpe)
    np.save(os.path.join(a.out, "tokens.npy"), ids.numpy().astype(np.int64))
    detail = []
    for p in prompts:
        norm = bpe.whitespace_clean(bpe.basic_clean(p)).lower()
        detail.append({"normalized": norm, "pieces": bpe.pre_tokenize(norm), "encoded": tok.encode(p)})
    with open(os.path.join(a.out, "text.json"), "w", encoding="utf-8") as f:
        json.dump(detail, f, ensure_ascii=False, indent=1)

    if a.checkpoint:
        import torch
        from spar_reference import cli
        torch.set_num_threads(2)
        sd = cli.load_checkpoint(a.checkpoint)
        cfg = cli.get_config(a.config, sd, a.checkpoint)
        _, clip_sd = cli.split_state_dict(sd)
        enc = cli.build_text_encoder(cfg, clip_sd, float64=True)
        with torch.no_grad():
            emb = enc(ids)
        np.save(os.path.join(a.out, "embeddings.npy"), emb.numpy().astype(np.float64))
    return 0


if __name__ == "__main__":
    sys.exit(main())
