#!/usr/bin/python3
"""Makes the real-footage figure of docs/render.md (docs/footage_vtest.png).

The README's real-footage figure (docs/footage_vtest.png): `spar render --video` on Debian
opencv-doc's vtest.avi (people walking past a fixed camera), three frames 0.4 s apart, the
first two inputs: each input frame, its P(dynamic) and its motion mask laid over it, and the
rendered third frame beside the real one.

    /usr/bin/python3 scripts/demo/footage_figure.py [SPAR]     (default build/bin/spar)
"""
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image, ImageDraw

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
VIDEO = "/usr/share/doc/opencv-doc/examples/data/vtest.avi"
TIMES = "62,62.4,62.8"
SCALE = 2  # 128 px -> 256 px a panel


def panel(im, title):
    im = im.convert("RGB").resize((128 * SCALE, 128 * SCALE), Image.NEAREST)
    out = Image.new("RGB", (im.width, im.height + 18), "white")
    out.paste(im, (0, 18))
    ImageDraw.Draw(out).text((4, 3), title, fill="black")
    return out


def main():
    spar = sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "build", "bin", "spar")
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "out")
        subprocess.run([spar, "render", "--model", os.path.join(ROOT, "data", "spar_rooms.spar"),
                        "--video", VIDEO, "--video-at", TIMES, "--inputs", "0,1", "--out", out], check=True)
        frames = []
        for t in TIMES.split(","):
            png = os.path.join(tmp, "frame_%s.png" % t)
            subprocess.run(["ffmpeg", "-v", "error", "-y", "-ss", t, "-i", VIDEO, "-frames:v", "1", "-vf",
                            "scale=128:128:force_original_aspect_ratio=increase:flags=lanczos,crop=128:128", png],
                           check=True)
            frames.append(Image.open(png).convert("RGB"))
        row = []
        for i in range(2):
            mask = np.asarray(Image.open(os.path.join(out, "mask_%02d.png" % i)).convert("L")) > 127
            over = np.asarray(frames[i]).copy()
            over[mask] = (0.4 * over[mask] + 0.6 * np.array([255, 40, 40])).astype(np.uint8)
            row += [panel(frames[i], "input %d (%s s)" % (i, TIMES.split(",")[i])),
                    panel(Image.open(os.path.join(out, "motion_%02d.png" % i)), "P(dynamic)"),
                    panel(Image.fromarray(over), "mask over the input")]
        row += [panel(Image.open(os.path.join(out, "view_00.png")), "rendered target"),
                panel(frames[2], "real target (%s s)" % TIMES.split(",")[2])]
        fig = Image.new("RGB", (sum(p.width for p in row), row[0].height), "white")
        x = 0
        for p in row:
            fig.paste(p, (x, 0))
            x += p.width
        dest = os.path.join(ROOT, "docs", "footage_vtest.png")
        fig.save(dest, optimize=True)
        print("wrote", dest, fig.size)


if __name__ == "__main__":
    main()
