#!/usr/bin/python3
"""Test fixture op_goldens: the goldens of the op- and host-level tests that need no model
fixture, made once per build (CTest test make_op_goldens) in one process, one directory each:

    make_op_goldens.py OUT_DIR

writes OUT_DIR/
    image/            make_image_golden.py   (tests/test_image_prep.cpp)
    path/             make_path_golden.py    (tests/test_cameras.cpp)
    camera/           make_camera_golden.py  (tests/test_plucker_rays.cpp)
    block/<case>/     make_block_golden.py, every case (tests/test_transformer_block.cpp)
    size/             make_size_model.py     (tests/test_spar_size.cpp)
    sam2_block/<case>/ make_sam2_block_golden.py (tests/test_sam2_hiera_block.cpp)
    sam2_path/        make_sam2_path_golden.py (tests/test_sam2_path.cpp)
"""
import os
import shutil
import sys


import make_block_golden  # noqa: E402
import make_camera_golden  # noqa: E402
import make_image_golden  # noqa: E402
import make_path_golden  # noqa: E402
import make_sam2_block_golden  # noqa: E402
import make_sam2_path_golden  # noqa: E402
import make_size_model  # noqa: E402


def main(out: str) -> int:
    shutil.rmtree(out, ignore_errors=True)
    make_image_golden.main(["--out", os.path.join(out, "image")])
    make_path_golden.main(["--out", os.path.join(out, "path")])
    make_camera_golden.main(["--out", os.path.join(out, "camera")])
    for case in sorted(make_block_golden.CASES) + sorted(make_block_golden.FP16_CASES):
        make_block_golden.main(["--case", case, "--out", os.path.join(out, "block", case)])
    make_size_model.main(os.path.join(out, "size"))
    make_sam2_block_golden.main(["--out", os.path.join(out, "sam2_block")])
    make_sam2_path_golden.main(["--out", os.path.join(out, "sam2_path")])
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    sys.exit(main(os.path.abspath(sys.argv[1])))
