#!/usr/bin/env bash
# Cross-builds the engine for arm64 and runs its self-test and op tests under qemu-user.
#
# The engine on 64-bit ARM (aarch64: the boards and phones it is for), without an ARM machine:
# built here with Debian's cross toolchain against Debian's arm64 packages, run under qemu-user
# on Debian's arm64 lavapipe (Mesa 22.3, the same driver as the x86-64 default, compiling
# aarch64 code with its own LLVM, which qemu then translates).
#
#   bash scripts/portability/arm64.sh setup    # crossbuild-essential-arm64 and qemu-user (apt-get, as
#                                  # install-deps.sh: root or sudo), and the arm64 sysroot: the
#                                  # packages below and everything they depend on, downloaded with
#                                  # a private apt state and unpacked (no dpkg, nothing installed)
#   bash scripts/portability/arm64.sh build    # build-arm64/: spar, spar-bench and the op test programs
#   bash scripts/portability/arm64.sh run PROGRAM ARGS...   # one arm64 program under qemu-aarch64
#   bash scripts/portability/arm64.sh test     # spar selftest, then the op test programs; each one's result
#                                  # and wall time, and a summary line (exit 0 only if all passed)
#
# DIR (default build-arm64) holds the sysroot (DIR/sysroot), its apt state and the build
# (DIR/build). Network: deb.debian.org (setup only). The validation layer runs as everywhere.
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
dir=${DIR:-build-arm64}
mkdir -p "$dir"
dir=$(cd "$dir" && pwd)
sysroot="$dir/sysroot"
build="$dir/build"
mode=${1:-}
shift || true

# What the engine, spar, spar-bench and the tests link or load at run time, for arm64 (the
# arm64 counterparts of install-deps.sh's libraries; header-only ones are architecture-free).
packages=(libvulkan-dev mesa-vulkan-drivers vulkan-validationlayers libopenimageio-dev openimageio-tools
          libgtest-dev nlohmann-json3-dev libcli11-dev libglm-dev libfmt-dev zlib1g-dev libicu-dev
          libstdc++-12-dev)
# The op programs (one op family each; test_transformer_block reads op goldens made here by the
# host's python, as CTest's fixture op_goldens does).
op_tests=(test_linear test_attention test_conv2d test_conv_transpose2d test_norm test_reduce_channels test_patchify
          test_pool test_resize test_unary test_binary test_copy2d test_rope test_embedding test_transformer_block)

if [ "$mode" = setup ]; then
  need=()
  for p in crossbuild-essential-arm64 qemu-user; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || need+=("$p")
  done
  if [ ${#need[@]} -gt 0 ]; then
    sudo=""
    [ "$(id -u)" -ne 0 ] && sudo=sudo
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends "${need[@]}"
  fi
  if [ ! -f "$sysroot/.complete" ]; then
    apt="$dir/apt"
    rm -rf "$sysroot"
    mkdir -p "$apt/lists/partial" "$apt/cache/archives/partial" "$sysroot"
    : > "$apt/status"  # nothing installed: apt resolves every dependency
    key=/usr/share/keyrings/debian-archive-keyring.gpg
    {
      echo "deb [arch=arm64 signed-by=$key] http://deb.debian.org/debian bookworm main"
      echo "deb [arch=arm64 signed-by=$key] http://deb.debian.org/debian bookworm-updates main"
      echo "deb [arch=arm64 signed-by=$key] http://deb.debian.org/debian-security bookworm-security main"
    } > "$apt/sources.list"
    opts=(-o APT::Architecture=arm64 -o APT::Architectures::=arm64 -o Dir::State::status="$apt/status"
          -o Dir::Etc::SourceList="$apt/sources.list" -o Dir::Etc::SourceParts=/dev/null
          -o Dir::Etc::Preferences=/dev/null -o Dir::Etc::PreferencesParts=/dev/null
          -o Dir::State::Lists="$apt/lists" -o Dir::Cache="$apt/cache" -o Debug::NoLocking=1)
    apt-get "${opts[@]}" update -q > "$dir/apt.log"
    apt-get "${opts[@]}" install --download-only --no-install-recommends -y -q "${packages[@]}" >> "$dir/apt.log"
    for deb in "$apt"/cache/archives/*.deb; do dpkg -x "$deb" "$sysroot"; done
    # Absolute symbolic links point into the sysroot, not at the host's files.
    while IFS= read -r link; do
      target=$(readlink "$link")
      case $target in
        /*) ln -sfn "$(realpath -m --relative-to="$(dirname "$link")" "$sysroot$target")" "$link";;
      esac
    done < <(find "$sysroot" -type l)
    # What update-alternatives would make on an installed system (dpkg -x runs no maintainer
    # script): the reference BLAS and LAPACK under their plain names (OpenCV, via OpenImageIO,
    # needs them).
    for alt in blas/libblas.so.3 lapack/liblapack.so.3; do
      ln -sfn "$alt" "$sysroot/usr/lib/aarch64-linux-gnu/$(basename $alt)"
    done
    touch "$sysroot/.complete"
  fi
  echo "arm64: sysroot $sysroot ($(ls "$dir"/apt/cache/archives/*.deb | wc -l) packages," \
       "$(du -sh "$sysroot" | cut -f1)), $(aarch64-linux-gnu-g++ --version | head -1), $(qemu-aarch64 --version | head -1)"
  exit 0
fi

[ -f "$sysroot/.complete" ] || { echo "arm64: no sysroot in $sysroot (bash scripts/portability/arm64.sh setup)" >&2; exit 1; }

if [ "$mode" = build ]; then
  cmake -S "$root" -B "$build" -DCMAKE_BUILD_TYPE=Release -DCMAKE_TOOLCHAIN_FILE="$root/cmake/aarch64-linux-gnu.cmake" \
        -DSPAR_ARM64_SYSROOT="$sysroot" -DSPAR_PYTHON=OFF > "$dir/configure.log"
  cmake --build "$build" -j"$(nproc)" --target spar spar-bench "${op_tests[@]}"
  file "$build/bin/spar" | cut -d, -f1-2
  exit 0
fi

# An arm64 program under qemu-aarch64: the sysroot is its / for libraries and data (the
# dynamic loader, the Vulkan loader's manifests, lavapipe, the validation layer).
run() {
  QEMU_LD_PREFIX="$sysroot" \
  VK_ICD_FILENAMES=/usr/share/vulkan/icd.d/lvp_icd.aarch64.json \
  VK_LAYER_PATH=/usr/share/vulkan/explicit_layer.d \
    qemu-aarch64 "$@"
}

if [ "$mode" = run ]; then
  [ $# -ge 1 ] || { echo "usage: bash scripts/portability/arm64.sh run PROGRAM ARGS..." >&2; exit 2; }
  run "$@"
  exit $?
fi

if [ "$mode" = test ]; then
  [ $# -eq 0 ] || { echo "usage: bash scripts/portability/arm64.sh test" >&2; exit 2; }
  export SPAR_VALIDATION=1 SPAR_OP_GOLDENS_DIR="$dir/op_goldens"
  [ -d "$SPAR_OP_GOLDENS_DIR" ] || PYTHONPATH="$(bash scripts/setup/pythonpath.sh)" /usr/bin/python3 tests/python/make_op_goldens.py "$SPAR_OP_GOLDENS_DIR" > /dev/null
  failed=0 total=0 t_all=$(date +%s)
  report() {  # NAME EXIT SECONDS
    total=$((total + 1))
    [ "$2" = 0 ] || failed=$((failed + 1))
    printf "arm64: %-28s %s  %5d s\n" "$1" "$([ "$2" = 0 ] && echo pass || echo "FAIL (exit $2)")" "$3"
  }
  t=$(date +%s) code=0
  run "$build/bin/spar" selftest > "$dir/selftest.log" 2>&1 || code=$?
  report "spar selftest" $code $(( $(date +%s) - t ))
  grep -E "^device|^validation|^verdict" "$dir/selftest.log" | sed 's/^/         /'
  for p in "${op_tests[@]}"; do
    t=$(date +%s) code=0
    run "$build/tests/$p" --gtest_brief=1 > "$dir/$p.log" 2>&1 || code=$?
    report "$p" $code $(( $(date +%s) - t ))
  done
  echo "arm64: $((total - failed)) of $total passed in $(( $(date +%s) - t_all )) s (logs: $dir/*.log)"
  [ $failed = 0 ]
  exit $?
fi

echo "usage: bash scripts/portability/arm64.sh setup | build | run PROGRAM ARGS... | test" >&2
exit 2
