#!/usr/bin/python3
"""Goldens for tests/test_image_prep.cpp: test images and PIL's prepared outputs.

Writes into --out a few images (odd sizes, grey, RGBA, JPEG, constant black and white, files
that are not images) and, for each case of CASES, the reference's prepared input
(``reference/spar_reference/images.py``'s ``load_image``, PIL's Lanczos) and the 8-bit RGB that
``ImageOps.exif_transpose(im).convert("RGB")`` gives (JPEGs with every EXIF orientation):

    <image file>                 the test image
    <case>.prepared.npy          load_image(<image>, H, W), [3, H, W] '<f4'
    <image stem>.rgb.npy         convert("RGB") pixels, [h, w, 3] '<i4'
    cases.txt                    one line per case: "<case> <image file> <H> <W>"

Usage: make_image_golden.py --out DIR
"""

import argparse
import os

import numpy as np
from PIL import Image, ImageOps

from spar_reference.images import load_image  # noqa: E402


def content(w: int, h: int, channels: int, seed: int) -> np.ndarray:
    """Smooth gradients, sharp edges and noise: every filter lobe and the clipping matter."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    planes = []
    for c in range(channels):
        v = 128 + 100 * np.sin(x / (5.0 + 3 * c) + y / (7.0 + c)) * np.cos(y / (11.0 + 2 * c))
        v += np.where(((x // (6 + c)) + (y // 9)) % 2 == 0, 60.0, -60.0)   # hard edges
        v += rng.normal(0, 25, size=(h, w))
        planes.append(v)
    a = np.clip(np.rint(np.stack(planes, axis=-1)), 0, 255).astype(np.uint8)
    a[0, :] = 255          # extreme rows/columns: overshoot and undershoot at the borders
    a[:, -1] = 0
    return a


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    out = args.out
    os.makedirs(out, exist_ok=True)

    images = {
        "rgb_150x180.png": Image.fromarray(content(150, 180, 3, 1), "RGB"),
        "rgb_37x61.png": Image.fromarray(content(37, 61, 3, 2), "RGB"),
        "rgb_301x97.png": Image.fromarray(content(301, 97, 3, 3), "RGB"),
        "rgb_64x100.png": Image.fromarray(content(64, 100, 3, 4), "RGB"),
        "rgb_101x300.png": Image.fromarray(content(101, 300, 3, 9), "RGB"),
        "rgb_300x101.png": Image.fromarray(content(300, 101, 3, 10), "RGB"),
        "rgb_48x48.png": Image.fromarray(content(48, 48, 3, 5), "RGB"),
        "grey_83x59.png": Image.fromarray(content(83, 59, 1, 6)[:, :, 0], "L"),
        "rgba_71x90.png": Image.fromarray(content(71, 90, 4, 7), "RGBA"),
        "black_50x70.png": Image.fromarray(np.zeros((70, 50, 3), np.uint8), "RGB"),
        "white_77x33.png": Image.fromarray(np.full((33, 77, 3), 255, np.uint8), "RGB"),
    }
    # The PNG kinds libpng's transforms expand (imaging/png_files.cpp): a palette, a palette with a
    # transparent entry (tRNS), 1-bit, grey with alpha; and a PNG with an EXIF orientation
    # (eXIf chunk), which OpenImageIO reads.
    images["palette_45x31.png"] = Image.fromarray(content(45, 31, 3, 11), "RGB").quantize(colors=37)
    images["palette_trns_29x23.png"] = Image.fromarray(content(29, 23, 3, 12), "RGB").quantize(colors=9)
    images["bits1_40x28.png"] = Image.fromarray(content(40, 28, 1, 13)[:, :, 0] > 127).convert("1")
    images["la_33x47.png"] = Image.fromarray(content(33, 47, 2, 14), "LA")
    for name, im in images.items():
        im.save(os.path.join(out, name), format="PNG", **({"transparency": 0} if "trns" in name else {}))
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.fromarray(content(27, 41, 3, 15), "RGB").save(os.path.join(out, "exif_o6_27x41.png"), format="PNG",
                                                        exif=exif.tobytes())
    Image.fromarray(content(123, 95, 3, 8), "RGB").save(os.path.join(out, "photo_123x95.jpg"), format="JPEG", quality=90)
    # The same photo with each EXIF orientation (2-8): shown turned or mirrored, prepared so.
    for o in range(2, 9):
        exif = Image.Exif()
        exif[0x0112] = o
        Image.fromarray(content(123, 95, 3, 8), "RGB").save(os.path.join(out, "photo_123x95_o%d.jpg" % o),
                                                            format="JPEG", quality=90, exif=exif.tobytes())
    with open(os.path.join(out, "not_an_image.png"), "wb") as f:
        f.write(b"this is not a PNG file\n" * 4)
    with open(os.path.join(out, "rgb_150x180.png"), "rb") as f:
        data = f.read()
    with open(os.path.join(out, "truncated.png"), "wb") as f:
        f.write(data[: len(data) // 3])

    cases = [
        ("down_150x180_64", "rgb_150x180.png", 64, 64),
        ("down_150x180_48x80", "rgb_150x180.png", 48, 80),
        ("down_150x180_97x33", "rgb_150x180.png", 97, 33),
        ("up_37x61_96", "rgb_37x61.png", 96, 96),
        ("up_37x61_70x50", "rgb_37x61.png", 70, 50),
        ("down_301x97_64", "rgb_301x97.png", 64, 64),
        ("up_301x97_128", "rgb_301x97.png", 128, 128),
        ("croponly_64x100_64", "rgb_64x100.png", 64, 64),
        ("vonly_101x300_299x100", "rgb_101x300.png", 299, 100),
        ("honly_300x101_100x299", "rgb_300x101.png", 100, 299),
        ("none_48x48_48", "rgb_48x48.png", 48, 48),
        ("grey_83x59_56", "grey_83x59.png", 56, 56),
        ("rgba_71x90_64", "rgba_71x90.png", 64, 64),
        ("jpeg_123x95_64", "photo_123x95.jpg", 64, 64),
        ("jpeg_123x95_160", "photo_123x95.jpg", 160, 160),
        *[("jpeg_o%d_64x48" % o, "photo_123x95_o%d.jpg" % o, 64, 48) for o in range(2, 9)],
        ("black_50x70_64", "black_50x70.png", 64, 64),
        ("white_77x33_40", "white_77x33.png", 40, 40),
        ("palette_45x31_40", "palette_45x31.png", 40, 40),
        ("palette_trns_29x23_24", "palette_trns_29x23.png", 24, 24),
        ("bits1_40x28_24", "bits1_40x28.png", 24, 24),
        ("la_33x47_32", "la_33x47.png", 32, 32),
        ("png_exif_o6_24x32", "exif_o6_27x41.png", 24, 32),
    ]
    with open(os.path.join(out, "cases.txt"), "w") as f:
        for case, image, h, w in cases:
            x = load_image(os.path.join(out, image), h, w, dtype=np.float32)
            assert x.shape == (3, h, w) and x.dtype == np.float32
            np.save(os.path.join(out, case + ".prepared.npy"), x)
            f.write(f"{case} {image} {h} {w}\n")
    for image in sorted(set(c[1] for c in cases)):
        with Image.open(os.path.join(out, image)) as im:
            rgb = np.asarray(ImageOps.exif_transpose(im).convert("RGB"), dtype=np.int32)
        np.save(os.path.join(out, os.path.splitext(image)[0] + ".rgb.npy"), rgb)


if __name__ == "__main__":
    main()
