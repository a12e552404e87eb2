#!/usr/bin/python3
"""Image preparation and PNG output of the reference's command-line tool.

Preparation rule (the C++ engine must reproduce it exactly):

1. Load with PIL, turn as the EXIF orientation says (``ImageOps.exif_transpose``: a phone
   photo held upright is upright), and convert to RGB (``Image.convert("RGB")``: palette, grey,
   alpha (dropped, not composited) and CMYK images become 8-bit RGB).
2. Resize with Lanczos (``Image.resize(size, Image.LANCZOS)``, PIL's 3-lobe Lanczos with its
   separable two-pass filter and support scaled to the downscale factor) so that the image
   covers the model's H x W: ``s = max(H / h, W / w)`` for an image of w x h pixels, new size
   ``nw = max(W, round(w * s))``, ``nh = max(H, round(h * s))`` (Python's round, half to even).
   For the square model sizes this is "the shorter side becomes the model size". No resize
   is done when (nw, nh) == (w, h).
3. Centre crop to H x W: ``left = (nw - W) // 2``, ``top = (nh - H) // 2``, pixels
   [left, left + W) x [top, top + H).
4. Values: the 8-bit samples divided by 255 (float32, or float64 with --float64), layout
   [3, H, W] (channel-first), in [0, 1]. The tokenizers see 2*x - 1 (inside the model).

Output PNGs: RGB images in [0,1] are written as round(clip(x, 0, 1) * 255) (half away from
zero, i.e. floor(x * 255 + 0.5)), 8-bit; probabilities likewise as 8-bit grey; binary masks
as 0 / 255.
"""

from typing import Tuple

import numpy as np


class ImageError(Exception):
    """An image that does not exist or cannot be read."""


def crop_geometry(w: int, h: int, out_w: int, out_h: int) -> Tuple[int, int, int, int]:
    """(nw, nh, left, top): the resized size and the crop origin of the preparation rule."""
    s = max(out_h / h, out_w / w)
    nw = max(out_w, int(round(w * s)))
    nh = max(out_h, int(round(h * s)))
    return nw, nh, (nw - out_w) // 2, (nh - out_h) // 2


def load_image(path: str, out_h: int, out_w: int, dtype=np.float32) -> np.ndarray:
    """The prepared image [3, out_h, out_w] in [0, 1] (see the module docstring)."""
    from PIL import Image, ImageOps
    try:
        with Image.open(path) as im:
            im.load()
            rgb = ImageOps.exif_transpose(im).convert("RGB")
    except FileNotFoundError:
        raise ImageError(f"image not found: {path}")
    except Exception as e:  # PIL.UnidentifiedImageError, OSError (truncated), ...
        raise ImageError(f"cannot read image {path}: {e.__class__.__name__}: {e}")
    w, h = rgb.size
    if w < 1 or h < 1:
        raise ImageError(f"empty image: {path}")
    nw, nh, left, top = crop_geometry(w, h, out_w, out_h)
    if (nw, nh) != (w, h):
        rgb = rgb.resize((nw, nh), Image.LANCZOS)
    rgb = rgb.crop((left, top, left + out_w, top + out_h))
    a = np.asarray(rgb, dtype=np.uint8)                      # [H, W, 3]
    return (a.astype(np.float64) / 255.0).transpose(2, 0, 1).astype(dtype)


def to_uint8(x: np.ndarray) -> np.ndarray:
    """[0,1] floats -> uint8, floor(clip(x, 0, 1) * 255 + 0.5)."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return np.floor(x * 255.0 + 0.5).astype(np.uint8)


def save_rgb(path: str, chw: np.ndarray) -> None:
    """[3, H, W] in [0,1] -> 8-bit RGB PNG."""
    from PIL import Image
    Image.fromarray(to_uint8(chw).transpose(1, 2, 0), "RGB").save(path, format="PNG")


def save_grey(path: str, hw: np.ndarray) -> None:
    """[H, W] in [0,1] -> 8-bit grey PNG."""
    from PIL import Image
    Image.fromarray(to_uint8(hw), "L").save(path, format="PNG")


def save_mask(path: str, hw: np.ndarray) -> None:
    """[H, W] bool -> 8-bit grey PNG with 0 / 255."""
    from PIL import Image
    Image.fromarray(np.where(np.asarray(hw, dtype=bool), 255, 0).astype(np.uint8), "L").save(
        path, format="PNG")


# Fixed palette of label maps (label k gets PALETTE[k % len(PALETTE)]).
PALETTE = [
    (230, 25, 75), (60, 180, 75), (255, 225, 25), (0, 130, 200), (245, 130, 48),
    (145, 30, 180), (70, 240, 240), (240, 50, 230), (210, 245, 60), (250, 190, 212),
    (0, 128, 128), (220, 190, 255), (170, 110, 40), (255, 250, 200), (128, 0, 0),
    (170, 255, 195), (128, 128, 0), (255, 215, 180), (0, 0, 128), (128, 128, 128),
]


def palette_colour(k: int) -> Tuple[int, int, int]:
    return PALETTE[k % len(PALETTE)]


def save_label_map(path: str, labels: np.ndarray, names, out_h: int, out_w: int) -> None:
    """Label map [h, w] (ints) -> colour PNG: the map scaled (nearest) to out_h x out_w, with a
    legend strip below it (one row per label: colour swatch and prompt)."""
    from PIL import Image, ImageDraw
    labels = np.asarray(labels)
    pal = np.array([palette_colour(k) for k in range(len(names))], dtype=np.uint8)
    rgb = pal[labels]                                        # [h, w, 3]
    img = Image.fromarray(rgb, "RGB").resize((out_w, out_h), Image.NEAREST)
    row = 14
    canvas = Image.new("RGB", (out_w, out_h + row * len(names) + 4), (0, 0, 0))
    canvas.paste(img, (0, 0))
    draw = ImageDraw.Draw(canvas)
    for k, name in enumerate(names):
        y = out_h + 2 + row * k
        draw.rectangle([2, y + 1, 12, y + row - 3], fill=palette_colour(k))
        draw.text((16, y), str(name), fill=(255, 255, 255))
    canvas.save(path, format="PNG")


def save_path_animation(path: str, views: np.ndarray, label_pngs, fps: int = 8) -> None:
    """path.gif of a --path render: each rendered view [3, H, W] (beside its label map image
    when ``label_pngs`` lists them), top-aligned on black, as a looping animated GIF."""
    from PIL import Image
    frames = []
    for j in range(views.shape[0]):
        parts = [Image.fromarray(to_uint8(views[j]).transpose(1, 2, 0), "RGB")]
        if label_pngs:
            parts.append(Image.open(label_pngs[j]).convert("RGB"))
        canvas = Image.new("RGB", (sum(p.width for p in parts), max(p.height for p in parts)))
        x = 0
        for p in parts:
            canvas.paste(p, (x, 0))
            x += p.width
        frames.append(canvas)
    frames[0].save(path, format="GIF", save_all=True, append_images=frames[1:],
                   duration=int(round(1000 / fps)), loop=0)
