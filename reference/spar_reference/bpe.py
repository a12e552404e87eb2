#!/usr/bin/python3
"""CLIP's byte-level BPE tokenizer (openai/CLIP ``clip/simple_tokenizer.py``), standard library only.

The merges table (``bpe_simple_vocab_16e6.txt.gz``) is read from a path given by the caller;
it is data and is not part of this repository.

Vocabulary (as CLIP builds it): the 256 byte symbols of ``bytes_to_unicode`` in its order, the
same 256 followed by ``</w>``, one entry per merge of lines 1..48894 of the file (line 0 is a
version header), then ``<|startoftext|>`` = 49406 and ``<|endoftext|>`` = 49407: 49408 ids.

Text -> ids:
  1. clean: CLIP runs ``ftfy.fix_text`` then ``html.unescape`` twice and strips.  ftfy is not
     available here, so ``_fix_text`` APPROXIMATES it with the standard library: ANSI terminal
     escapes and control characters removed, Latin ligatures split (U+FB00-FB06, U+0132/0133,
     U+01C4-01CC, U+01F1-01F3), full-width forms folded to ASCII, curly quotes straightened,
     line separators unified, then NFC.  Not reproduced: ftfy's mojibake repair (fix_encoding,
     C1-control decoding as windows-1252, lossy-sequence repair).  Clean UTF-8 text gives
     the same ids as CLIP.
  2. whitespace runs -> one space, strip, lower-case.
  3. split with CLIP's pattern ``<|startoftext|>|<|endoftext|>|'s|'t|'re|'ve|'m|'ll|'d|[\\p{L}]+|
     [\\p{N}]|[^\\s\\p{L}\\p{N}]+`` (written out as a scanner: letters = Unicode category L*,
     numbers = N*, whitespace = the Unicode White_Space set, as the ``regex`` module has them).
  4. each piece as UTF-8 bytes -> byte symbols -> BPE merges (lowest rank first, the last
     symbol carrying ``</w>``) -> ids.
``tokenize`` adds start/end tokens and pads with 0 to ``context_length``; a longer sequence is
truncated to context_length with the end token put back last (CLIP's ``truncate=True``); with
``truncate=False`` it raises, as CLIP's default does (SPAR and LSeg call ``clip.tokenize``
with that default).  Ids are returned as int64 (CLIP returns int32 on torch >= 1.8).
"""
import gzip
import html
import unicodedata
from functools import lru_cache
from typing import Dict, Iterable, List, Sequence, Tuple, Union

SOT = "<|startoftext|>"
EOT = "<|endoftext|>"
N_MERGES = 49152 - 256 - 2  # 48894


@lru_cache()
def bytes_to_unicode() -> Dict[int, str]:
    """Byte -> printable unicode symbol (printable Latin-1 bytes keep their character, the
    others are mapped to 256, 257, ... in byte order)."""
    keep = list(range(ord("!"), ord("~") + 1)) + list(range(ord("\xa1"), ord("\xac") + 1)) \
        + list(range(ord("\xae"), ord("\xff") + 1))
    symbols = {b: chr(b) for b in keep}
    extra = 0
    order = list(keep)
    for b in range(256):
        if b not in symbols:
            symbols[b] = chr(256 + extra)
            order.append(b)
            extra += 1
    return {b: symbols[b] for b in order}  # dict in CLIP's order (kept bytes first)


# ----------------------------------------------------------------------------------- cleaning

_WHITE_SPACE = set("\t\n\x0b\x0c\r \x85\xa0\u1680\u2028\u2029\u202f\u205f\u3000") | \
    {chr(c) for c in range(0x2000, 0x200B)}


def _is_space(ch: str) -> bool:
    return ch in _WHITE_SPACE


def _is_letter(ch: str) -> bool:
    return unicodedata.category(ch).startswith("L")


def _is_number(ch: str) -> bool:
    return unicodedata.category(ch).startswith("N")


_LIGATURES = {c: unicodedata.normalize("NFKC", c) for c in
              "\u0132\u0133\u01c4\u01c5\u01c6\u01c7\u01c8\u01c9\u01ca\u01cb\u01cc\u01f1\u01f2\u01f3"
              "\ufb00\ufb01\ufb02\ufb03\ufb04\ufb05\ufb06"}
_QUOTES = {"\u2018": "'", "\u2019": "'", "\u201a": "'", "\u201b": "'",
           "\u201c": '"', "\u201d": '"', "\u201e": '"', "\u201f": '"'}


def _width(ch: str) -> str:
    o = ord(ch)
    if o == 0x3000:
        return " "
    if 0xFF01 <= o <= 0xFFEE:
        n = unicodedata.normalize("NFKC", ch)
        return n if len(n) == 1 else ch
    return ch


def _is_removed_control(ch: str) -> bool:
    o = ord(ch)
    return (o <= 0x08 or o == 0x0B or 0x0E <= o <= 0x1F or o == 0x7F
            or 0x206A <= o <= 0x206F or o == 0xFEFF or 0xFFF9 <= o <= 0xFFFC
            or 0x1D173 <= o <= 0x1D17A or 0xE0000 <= o <= 0xE007F)


def _strip_terminal_escapes(text: str) -> str:
    out, i, n = [], 0, len(text)
    while i < n:
        if text[i] == "\x1b" and i + 1 < n and text[i + 1] == "[":
            j = i + 2
            while j < n and (text[j].isdigit() or text[j] == ";"):
                j += 1
            if j < n and ("a" <= text[j] <= "z" or "A" <= text[j] <= "Z"):
                i = j + 1
                continue
        out.append(text[i])
        i += 1
    return "".join(out)


def _fix_text(text: str) -> str:
    """Standard-library approximation of ftfy.fix_text (see the module docstring)."""
    text = _strip_terminal_escapes(text)
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    out = []
    for ch in text:
        if _is_removed_control(ch):
            continue
        ch = _LIGATURES.get(ch, ch)
        ch = _QUOTES.get(ch, ch)
        out.append(_width(ch) if len(ch) == 1 else ch)
    return unicodedata.normalize("NFC", "".join(out))


def basic_clean(text: str) -> str:
    text = _fix_text(text)
    text = html.unescape(html.unescape(text))
    return text.strip()


def whitespace_clean(text: str) -> str:
    out, in_space = [], False
    for ch in text:
        if _is_space(ch):
            if not in_space:
                out.append(" ")
            in_space = True
        else:
            out.append(ch)
            in_space = False
    return "".join(out).strip()


_CONTRACTIONS = ("'s", "'t", "'re", "'ve", "'m", "'ll", "'d")


def pre_tokenize(text: str) -> List[str]:
    """CLIP's regular expression, alternatives tried in order at each position."""
    pieces, i, n = [], 0, len(text)
    while i < n:
        if text.startswith(SOT, i):
            pieces.append(SOT)
            i += len(SOT)
            continue
        if text.startswith(EOT, i):
            pieces.append(EOT)
            i += len(EOT)
            continue
        c = next((c for c in _CONTRACTIONS if text.startswith(c, i)), None)
        if c is not None:
            pieces.append(c)
            i += len(c)
            continue
        ch = text[i]
        if _is_letter(ch):
            j = i + 1
            while j < n and _is_letter(text[j]):
                j += 1
        elif _is_number(ch):
            j = i + 1
        elif _is_space(ch):
            i += 1
            continue
        else:
            j = i + 1
            while j < n and not (_is_space(text[j]) or _is_letter(text[j]) or _is_number(text[j])):
                j += 1
        pieces.append(text[i:j])
        i = j
    return pieces


# ---------------------------------------------------------------------------------- tokenizer

class BPETokenizer:
    def __init__(self, merges_path: str):
        with gzip.open(merges_path, "rb") as f:
            lines = f.read().decode("utf-8").split("\n")
        merges = [tuple(line.split()) for line in lines[1:N_MERGES + 1]]
        if len(merges) != N_MERGES or any(len(m) != 2 for m in merges):
            raise ValueError(f"{merges_path}: expected {N_MERGES} merges after the header")
        self.byte_encoder = bytes_to_unicode()
        self.byte_decoder = {v: k for k, v in self.byte_encoder.items()}
        vocab = list(self.byte_encoder.values())
        vocab = vocab + [v + "</w>" for v in vocab]
        vocab += ["".join(m) for m in merges]
        vocab += [SOT, EOT]
        self.encoder = {tok: i for i, tok in enumerate(vocab)}
        if len(self.encoder) != len(vocab):
            raise ValueError("duplicate vocabulary entries")
        self.decoder = {i: tok for tok, i in self.encoder.items()}
        self.ranks = {m: r for r, m in enumerate(merges)}
        self.sot = self.encoder[SOT]
        self.eot = self.encoder[EOT]
        self._cache = {SOT: [SOT], EOT: [EOT]}

    @property
    def vocab_size(self) -> int:
        return len(self.encoder)

    def bpe(self, piece: str) -> List[str]:
        """Merge the symbols of one pre-token (already byte-mapped)."""
        if piece in self._cache:
            return self._cache[piece]
        word = list(piece[:-1]) + [piece[-1] + "</w>"]
        while len(word) > 1:
            best, best_rank = None, None
            for pair in zip(word[:-1], word[1:]):
                r = self.ranks.get(pair)
                if r is not None and (best_rank is None or r < best_rank):
                    best, best_rank = pair, r
            if best is None:
                break
            merged, i = [], 0
            while i < len(word):
                if i < len(word) - 1 and word[i] == best[0] and word[i + 1] == best[1]:
                    merged.append(best[0] + best[1])
                    i += 2
                else:
                    merged.append(word[i])
                    i += 1
            word = merged
        self._cache[piece] = word
        return word

    def encode(self, text: str) -> List[int]:
        text = whitespace_clean(basic_clean(text)).lower()
        ids = []
        for piece in pre_tokenize(text):
            if piece in (SOT, EOT):
                ids.append(self.encoder[piece])
                continue
            mapped = "".join(self.byte_encoder[b] for b in piece.encode("utf-8"))
            ids.extend(self.encoder[t] for t in self.bpe(mapped))
        return ids

    def decode(self, ids: Iterable[int]) -> str:
        text = "".join(self.decoder[int(i)] for i in ids)
        data = bytearray(self.byte_decoder[c] for c in text if c in self.byte_decoder)
        return data.decode("utf-8", errors="replace").replace("</w>", " ")

    def tokenize(self, texts: Union[str, Sequence[str]], context_length: int = 77,
                 truncate: bool = True):
        import torch
        if isinstance(texts, str):
            texts = [texts]
        result = torch.zeros(len(texts), context_length, dtype=torch.long)
        for row, text in enumerate(texts):
            ids = [self.sot] + self.encode(text) + [self.eot]
            if len(ids) > context_length:
                if not truncate:
                    raise ValueError(f"input {text!r} is too long for context length {context_length}")
                ids = ids[:context_length]
                ids[-1] = self.eot
            result[row, :len(ids)] = torch.tensor(ids, dtype=torch.long)
        return result


@lru_cache(maxsize=4)
def get_tokenizer(merges_path: str) -> BPETokenizer:
    return BPETokenizer(merges_path)


def tokenize(texts: Union[str, Sequence[str]], merges_path: str, context_length: int = 77,
             truncate: bool = True):
    """[len(texts), context_length] int64 ids: start, BPE ids, end, zeros."""
    return get_tokenizer(str(merges_path)).tokenize(texts, context_length, truncate)
