#!/usr/bin/python3
"""The docs read as a manual: short sentences, a short README (CTest docs_style).

    /usr/bin/python3 scripts/checks/docs_style.py [--list N]

Rules: README.md at most 120 lines and no sentence over 50 words; docs/*.md together at most 10
sentences over 60 words. --list N prints every sentence over N words with its file and line.

A sentence is prose: code blocks, inline code, link targets, table rows and headings are left
out; a sentence ends at ". ", "? ", "! ", ": " before a list, a blank line, or a list item's end.
Words are what is between spaces. Exit 1 and one line per finding.
"""
import glob
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
README_LINES, README_WORDS, DOCS_WORDS, DOCS_LONG = 120, 50, 60, 10
# a full stop that ends a sentence: after a word of 2+ letters or a digit or a closing mark,
# not inside "e.g." / "i.e." / "vs." / "etc." abbreviations or decimals
ABBREVIATIONS = ("e.g.", "i.e.", "vs.", "etc.", "cf.", "approx.", "Fig.", "no.")


def prose_blocks(text):
    """(first line number, text) of each paragraph or list item of prose."""
    text = re.sub(r"```.*?```", lambda m: "\n" * m.group(0).count("\n"), text, flags=re.S)
    blocks, current, start = [], [], 0
    for number, line in enumerate(text.split("\n"), 1):
        stripped = line.strip()
        item = re.match(r"^\s*([-*+]|\d+\.)\s+", line)
        if not stripped or stripped.startswith(("#", "|", "<", "    ")) or line.startswith("    ") or item:
            if current:
                blocks.append((start, " ".join(current)))
            current = []
            if item:
                current, start = [line[item.end():].strip()], number
            continue
        if not current:
            start = number
        current.append(stripped)
    if current:
        blocks.append((start, " ".join(current)))
    return blocks


def sentences(block):
    block = re.sub(r"`[^`]*`", "CODE", block)
    block = re.sub(r"\]\([^)]*\)", "]", block)  # link targets
    for abbreviation in ABBREVIATIONS:
        block = block.replace(abbreviation, abbreviation.replace(".", ""))
    return [s for s in re.split(r"(?<=[A-Za-z0-9)\]\"'*_%])[.?!]\s+(?=[A-Z0-9(\"'*_`\[])", block) if s.strip()]


def long_sentences(path, limit):
    out = []
    for line, block in prose_blocks(open(path, encoding="utf-8").read()):
        for s in sentences(block):
            words = len(s.split())
            if words > limit:
                out.append((os.path.relpath(path, ROOT), line, words, s))
    return out


def main():
    listing = int(sys.argv[sys.argv.index("--list") + 1]) if "--list" in sys.argv else None
    findings = []
    readme = os.path.join(ROOT, "README.md")
    lines = open(readme, encoding="utf-8").read().count("\n")
    if lines > README_LINES:
        findings.append(f"README.md: {lines} lines (at most {README_LINES})")
    for f, line, words, s in long_sentences(readme, README_WORDS):
        findings.append(f"README.md:{line}: a sentence of {words} words (at most {README_WORDS}): {s[:80]}...")
    docs = sorted(glob.glob(os.path.join(ROOT, "docs", "*.md")))
    long = [x for path in docs for x in long_sentences(path, DOCS_WORDS)]
    if len(long) > DOCS_LONG:
        findings.append(f"docs/*.md: {len(long)} sentences over {DOCS_WORDS} words (at most {DOCS_LONG})")
    if listing is not None:
        for f, line, words, s in sorted((x for p in [readme] + docs for x in long_sentences(p, listing)),
                                        key=lambda x: -x[2]):
            print(f"{words:4d} {f}:{line}: {s[:100]}")
    for f in findings:
        print(f)
    print(f"docs_style: {len(findings)} finding(s); README {lines} lines, docs {len(long)} sentences over {DOCS_WORDS} words")
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())
