#!/usr/bin/python3
"""Render a scene with `import spar`: the shipped model on the shipped scene (or your photos),
its target view, a path of views through the input cameras, and label maps from prompts.

    PYTHONPATH=build/python python3 examples/python/render_scene.py OUT_DIR [PHOTO ...]
    (after `cmake --install build --prefix P`: PYTHONPATH=P/lib/python3/dist-packages)
"""
import os
import sys

import numpy as np

import spar

here = os.path.dirname(os.path.abspath(__file__))
data = os.path.join(here, "..", "..", "data")
out = sys.argv[1] if len(sys.argv) > 1 else "out/python"
photos = sys.argv[2:] or [os.path.join(data, "scenes", "scene_1000002", "rgb_0%d.png" % i) for i in (0, 4, 7)]
os.makedirs(out, exist_ok=True)

context = spar.Context()                      # the first GPU, else a CPU Vulkan device
model = spar.Model.open(os.path.join(data, "spar_rooms.spar"))
h, w = model.image_size
images = np.stack([spar.load_image(p, h, w) for p in photos])
with spar.Session(context, model) as session:
    # every photo an input; the cameras and motion come back as NumPy arrays
    enc = session.encode(images, semantic_features=True)
    print("canonical view", enc["canonical_index"], "dynamic share per input",
          np.round((enc["motion_input"] > 0.5).mean(axis=(1, 2)), 3))
    c2w, k = spar.path_cameras(enc, list(range(len(photos))), 8)
    views = session.render(c2w, k)            # (8, 3, H, W) in [0, 1]
    for i, rgb in enumerate(views):
        spar.write_png(os.path.join(out, "path_%02d.png" % i), rgb)
    labels = ["wall", "floor", "sofa", "bed", "table", "window"]
    maps = session.label_maps(labels)          # (8, H/2, W/2) prompt indices
    share = np.bincount(maps.ravel(), minlength=len(labels)) / maps.size
    print("labels:", ", ".join("%s %.0f%%" % (l, 100 * s) for l, s in zip(labels, share)))
    for t in session.stage_times():
        print("  %-16s %7.1f ms compute, %7.1f ms wall" % (t["name"], t["gpu_ms"], t["wall_ms"]))
print("wrote", len(views), "views to", out)
