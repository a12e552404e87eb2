#!/usr/bin/python3
"""Every local link of the repository's markdown files points at a file that exists (CTest docs_links).

    /usr/bin/python3 tests/check_links.py [FILE.md ...]    (default: every *.md but build folders')

Links are markdown's [text](target) and ![alt](target); web addresses (scheme://) and
in-page anchors (#...) are not checked; a target's own #anchor is dropped. Exit 1 and one line
per broken link.
"""
import glob
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def broken(path):
    text = open(path, encoding="utf-8").read()
    # code spans and blocks are not links
    text = re.sub(r"```.*?```", "", text, flags=re.S)
    text = re.sub(r"`[^`\n]*`", "", text)
    for target in LINK.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue
        local = target.split("#", 1)[0]
        if not os.path.exists(os.path.join(os.path.dirname(path), local)):
            yield target


def main(argv):
    files = argv or sorted(f for f in glob.glob(os.path.join(ROOT, "**", "*.md"), recursive=True)
                           if not os.path.relpath(f, ROOT).startswith(("build", "out" + os.sep)))
    bad = [(f, t) for f in files for t in broken(f)]
    for f, t in bad:
        print("%s: broken link: %s" % (os.path.relpath(f, ROOT), t))
    print("check_links: %d files, %d broken links" % (len(files), len(bad)))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
