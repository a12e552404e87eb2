#!/bin/sh
# The installed package as a user meets it: `cmake --install` into an empty prefix, the example
# (examples/render_one_view) configured with find_package(spar) against that prefix only, built,
# and run on the shipped model and scene under the validation layer. Checks that the example
# links libspar and nothing of the engine's private dependencies, and that the view it wrote
# has the model's size and is not blank; the installed `spar selftest` passes with the
# self-test model installed beside it.
#   install_example.sh BUILD_DIR SOURCE_DIR WORK_DIR
set -eu
build=$1 src=$2 work=$3
rm -rf "$work"
mkdir -p "$work"
cmake --install "$build" --prefix "$work/prefix" > "$work/install.log"
test -f "$work/prefix/include/spar/spar.h"
test -f "$work/prefix/lib/pkgconfig/spar.pc"
test -x "$work/prefix/bin/spar"
# The installed `spar selftest` passes and runs the self-test model installed with it (not the
# source tree's: SPAR_SELFTEST_DATA unset, share/spar/selftest beside its bin/).
env -u SPAR_SELFTEST_DATA SPAR_VALIDATION=1 "$work/prefix/bin/spar" selftest --json > "$work/selftest.json"
/usr/bin/python3 - "$work/selftest.json" "$work/prefix/share/spar/selftest" <<'PY'
import json, sys
doc = json.load(open(sys.argv[1]))
assert doc["passed"], "installed spar selftest failed"
assert doc["model"]["dir"] == sys.argv[2], doc["model"]["dir"]
assert len(doc["model"]["checks"]) == 25 and all(c["passed"] for c in doc["model"]["checks"])
print("installed spar selftest: passed, model from", doc["model"]["dir"])
PY
if ls "$work/prefix/include/spar" | grep -qv '\.h$'; then echo "non-header in include/spar"; exit 1; fi
if grep '#include' "$work/prefix/include/spar/"*.h | grep -v '"spar/\|<[a-z_]*>'; then
  echo "a public header includes something other than spar/ and the standard library"; exit 1
fi
cmake -S "$src/examples/render_one_view" -B "$work/build" -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_PREFIX_PATH="$work/prefix" > "$work/configure.log"
cmake --build "$work/build" > "$work/build.log"
# `import spar` from the prefix with the README's one line (PYTHONPATH), from another directory.
# A JPEG through the prefix's image-file module (lib/spar/, two folders above the Python module).
/usr/bin/python3 -c "from PIL import Image; Image.open('$src/data/scenes/scene_1000002/rgb_00.png').save('$work/rgb_00.jpg', quality=95)"
(cd "$work" && PYTHONPATH="$work/prefix/lib/python3/dist-packages" LD_DEBUG=files LD_DEBUG_OUTPUT="$work/ldpy" \
  /usr/bin/python3 -c "
import spar
m = spar.Model.open('$work/prefix/share/spar/spar_rooms.spar')
assert m.image_size == (128, 128) and spar.__file__.startswith('$work/prefix/'), spar.__file__
assert spar.load_image('$work/rgb_00.jpg', 128, 128).shape == (3, 128, 128)
print('import spar from', spar.__file__)")
grep -q "file=$work/prefix/lib/spar/spar_image_files.so" "$work"/ldpy.* || { echo "python: not the installed image-file module"; exit 1; }
# The same example built as the README's pkg-config line does, from the pkg-config file alone
# (its prefix relative to its own place, not the build's configured one).
flags=$(PKG_CONFIG_PATH="$work/prefix/lib/pkgconfig" pkg-config --cflags --libs spar)
echo "pkg-config: $flags"
case "$flags" in *"$work/prefix/lib/pkgconfig/../../include"*) ;; *) echo "pkg-config: not the scratch prefix"; exit 1;; esac
c++ -O1 "$src/examples/render_one_view/render_one_view.cpp" $flags -o "$work/render_one_view_pc"
LD_LIBRARY_PATH="$work/prefix/lib" "$work/render_one_view_pc" 2>&1 | grep -q "usage" || { echo "pkg-config build does not run"; exit 1; }
needed=$(readelf -d "$work/build/render_one_view" | grep NEEDED)
echo "$needed"
echo "$needed" | grep -q 'libspar\.so'
if echo "$needed" | grep -qi 'vulkan\|OpenImageIO\|icu\|libz'; then echo "the example links a private dependency"; exit 1; fi
scene="$src/data/scenes/scene_1000002"
# One photo as JPEG (made above): formats other than PNG are read through the installed
# image-file module (lib/spar/, loaded on first use by the libspar beside it:
# imaging/image_files.h), not the build tree's.
SPAR_VALIDATION=1 LD_DEBUG=files LD_DEBUG_OUTPUT="$work/ld" "$work/build/render_one_view" \
  "$work/prefix/share/spar/spar_rooms.spar" "$work/view.png" \
  "$work/rgb_00.jpg" "$scene/rgb_04.png" "$scene/rgb_07.png" 2> "$work/stderr.txt"
cat "$work/stderr.txt"
grep -h "file=.*spar_image_files.so" "$work"/ld.* | head -1
grep -q "file=$work/prefix/lib/spar/spar_image_files.so" "$work"/ld.* || { echo "not the installed image-file module"; exit 1; }
if grep -qi 'validation' "$work/stderr.txt"; then echo "validation messages"; exit 1; fi
/usr/bin/python3 - "$work/view.png" <<'PY'
import sys
from PIL import Image
im = Image.open(sys.argv[1]).convert("RGB")
assert im.size == (128, 128), im.size
lo, hi = zip(*im.getextrema())
assert max(h - l for l, h in zip(lo, hi)) > 20, "blank view: %s" % (im.getextrema(),)
print("view.png", im.size, "extrema", im.getextrema())
PY
