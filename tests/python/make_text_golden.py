#!/usr/bin/python3
"""Goldens of the text side for tests/test_bpe_tokenizer.cpp and tests/test_clip_text.cpp,
made at test time by the PyTorch reference (reference/spar_reference):

    make_text_golden.py --bpe MERGES.txt.gz (--prompts PROMPTS.json | --random N --seed S) --out DIR
                        [--checkpoint CK.pt --config CFG.json]

PROMPTS.json is a JSON list of strings (UTF-8); --random makes N random prompts instead (see
random_prompts) and writes them to DIR/prompts.json. Writes DIR/
    tokens.npy        int64 [P, 77]: bpe.tokenize(prompts) (truncate=True, as cli.py)
    text.json         per prompt: {"normalized": the cleaned, lower-cased text, "pieces": the
                      pre-tokens, "encoded": bpe ids without start/end tokens}
    embeddings.npy    float64 [P, E] (with --checkpoint): the checkpoint's CLIP text encoder,
                      built as cli.py build_text_encoder does, run in float64 on tokens.npy
"""
import argparse
import json
import os
import random
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))

from spar_reference import bpe  # noqa: E402


# Pieces that meet every rule of bpe.py: HTML references (named with and without ';', prefixes,
# numeric, invalid), terminal escapes, CR/LF, contractions, curly quotes, combining marks, case
# specials, CJK, emoji and joiners, full-width forms, ligatures, removed controls, white space of
# every kind, numbers of every category, special tokens.
PIECES = ["&", "#", "x", "X", ";", "0", "1", "9", "a", "F", "amp", "lt", "nbsp", "copy", "notin", "not", "AElig",
          " ", "  ", "\t", "\n", "\r", "\r\n", "\x1b[", "\x1b", "[", "m", "31", "'", "'s", "'ll", "\u2019", "\u201c",
          "\u00e9", "e\u0301", "\u00df", "\u0130", "\u03a3", "\u039f\u03a3", "\u732b", "\U0001F431", "\u200d",
          "\u3000", "\uff21", "\uff41", "\ufb01", "\u01c4", "\u00a0", "\u2028", "\x85", "\x1c", "\x00", "\x7f",
          "\u00ad", "\u00b2", "\u00bd", "\u2167", "\u0663", "<|endoftext|>", "<|startoftext|>", "&#", "&#x", "&amp;",
          "hello", "WORLD", "123", "...", "!?", "-", "\U0001F3FD", "\u0345", "\u0132", "\u01c5", "\u202f", "\u180e",
          "\u200b", "\ufeff", "\U000E0001", "\u2066", "&Amacr", "&amp", "&ampx", "&#1114112;", "&#55296", "&#x80;",
          "&#13;", "&#129;", "&#65534;", "a" * 40]


def random_prompts(n: int, seed: int):
    """Half from PIECES, half random code points of every plane in use (not surrogates),
    including ones assigned after the reference's Unicode version."""
    rng = random.Random(seed)

    def code_point():
        while True:
            c = rng.choice([rng.randint(0x20, 0x2FF), rng.randint(0x300, 0x3FFF), rng.randint(0x4000, 0xFFFF),
                            rng.randint(0x10000, 0x3FFFF), rng.randint(0xE0000, 0xE01EF)])
            if not 0xD800 <= c <= 0xDFFF:
                return chr(c)
    out = []
    for i in range(n):
        if i % 2 == 0:
            out.append("".join(rng.choice(PIECES) for _ in range(rng.randint(0, 25))))
        else:
            out.append("".join(code_point() if rng.random() < 0.7 else rng.choice(" aZ1&;#'")
                               for _ in range(rng.randint(1, 12))))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--bpe", required=True)
    ap.add_argument("--prompts")
    ap.add_argument("--random", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", required=True)
    ap.add_argument("--checkpoint")
    ap.add_argument("--config")
    a = ap.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    if a.random:
        prompts = random_prompts(a.random, a.seed)
        with open(os.path.join(a.out, "prompts.json"), "w", encoding="utf-8") as f:
            json.dump(prompts, f, ensure_ascii=False)
    else:
        with open(a.prompts, encoding="utf-8") as f:
            prompts = json.load(f)

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
        torch.set_num_threads(1)  # fixtures run beside another test (ctest -j2)
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
