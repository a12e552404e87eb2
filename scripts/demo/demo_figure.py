#!/usr/bin/python3
"""Makes the README's demo picture (docs/demo.png) from the demo's output.

The README's picture (docs/demo.png) from the demo's real output (scripts/demo/demo.sh, out/demo):
the three input frames with their motion masks over them (red), then four of the rendered views
along the camera path, each above its label map (wall red, floor green, ceiling yellow).

    /usr/bin/python3 scripts/demo/demo_figure.py          (runs scripts/demo/demo.sh first when out/demo is missing)
"""
import os
import subprocess

import numpy as np
from PIL import Image

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
OUT = os.path.join(ROOT, "out", "demo")
SIDE = 160


def load(name):
    return Image.open(os.path.join(OUT, name)).convert("RGB")


def main():
    if not os.path.isfile(os.path.join(OUT, "index.html")):
        subprocess.run(["bash", os.path.join(ROOT, "scripts", "demo", "demo.sh")], check=True)
    tiles = []
    for k in range(3):
        img = np.asarray(load("input_%02d.png" % k)).astype(np.float64)
        mask = np.asarray(Image.open(os.path.join(OUT, "mask_%02d.png" % k)).convert("L")) > 127
        img[mask] = 0.45 * img[mask] + 0.55 * np.array([230, 30, 30])
        tiles.append((Image.fromarray(img.astype(np.uint8)), None))
    for j in (0, 8, 16, 23):
        labels = load("labels_%02d.png" % j)
        labels = labels.crop((0, 0, labels.width, labels.width))  # the map; its legend is the README's text
        tiles.append((load("view_%02d.png" % j), labels))
    gap = 6
    width = len(tiles) * (SIDE + gap) + 4 * gap
    label_h = max(int(l.height * SIDE / l.width) for _, l in tiles if l is not None)
    fig = Image.new("RGB", (width, SIDE + label_h + 2 * gap), "white")
    x = gap
    for i, (top, below) in enumerate(tiles):
        if i == 3:
            x += 2 * gap  # inputs | rendered
        fig.paste(top.resize((SIDE, SIDE), Image.LANCZOS), (x, gap))
        if below is not None:
            fig.paste(below.resize((SIDE, int(below.height * SIDE / below.width)), Image.LANCZOS), (x, SIDE + gap))
        x += SIDE + gap
    fig = fig.crop((0, 0, x + gap, fig.height))
    dest = os.path.join(ROOT, "docs", "demo.png")
    fig.save(dest, optimize=True)
    print("wrote", dest, fig.size, os.path.getsize(dest), "bytes")


if __name__ == "__main__":
    main()
