#!/usr/bin/env bash
# Fetches Mesa 26.1's lavapipe (cooperative matrices) beside the build and runs programs on it.
#
# A Vulkan driver with VK_KHR_cooperative_matrix for the cooperative-matrix tests, on a machine
# without a GPU: Mesa's lavapipe 26.1 from Debian's trixie-backports (Debian 12's 22.3 and
# bookworm-backports' 25.0 have no cooperative matrices), with trixie's C library, Vulkan loader
# and validation layer (which knows the extension), downloaded and unpacked beside the build.
# Programs of this build run on it through trixie's dynamic loader; the system is untouched.
#
#   bash scripts/portability/coopmat-lavapipe.sh                 # fetch and unpack once
#   bash scripts/portability/coopmat-lavapipe.sh run PROGRAM ... # run one program of this build on it
#
# Needs network access to deb.debian.org (apt-get download, no root). DIR (default
# build/mesa-trixie) holds the apt state, the .debs and the unpacked root.
set -euo pipefail
cd "$(dirname "$0")/../.."
dir=${DIR:-build/mesa-trixie}
mkdir -p "$dir"
dir=$(cd "$dir" && pwd)
root="$dir/root"
lib="$root/usr/lib/x86_64-linux-gnu"
icd="$dir/lvp_icd.json"

if [ ! -f "$icd" ]; then
  mkdir -p "$dir/apt/lists/partial" "$dir/apt/cache/archives/partial"
  key=/usr/share/keyrings/debian-archive-keyring.gpg
  printf '%s\n' "deb [signed-by=$key] http://deb.debian.org/debian trixie main" \
                "deb [signed-by=$key] http://deb.debian.org/debian trixie-backports main" > "$dir/apt/sources.list"
  : > "$dir/apt/status"  # an empty package database: apt fetches the whole closure
  apt_opts=(-o Dir::Etc::SourceList="$dir/apt/sources.list" -o Dir::Etc::SourceParts=/dev/null
            -o Dir::State::Lists="$dir/apt/lists" -o Dir::Cache="$dir/apt/cache"
            -o Dir::State::status="$dir/apt/status" -o Debug::NoLocking=1 -o APT::Sandbox::User=root)
  apt-get "${apt_opts[@]}" update -q >/dev/null
  # libglvnd0: not for lavapipe; NVIDIA's Vulkan driver (libGLX_nvidia.so.0) needs its
  # libGLdispatch.so.0, which the GPU check's bundle carries (scripts/gpu/gpu-check.sh pack).
  apt-get "${apt_opts[@]}" install --download-only -y -q --no-install-recommends \
    mesa-vulkan-drivers/trixie-backports libvulkan1 vulkan-validationlayers libglvnd0 >/dev/null
  rm -rf "$root.tmp" && mkdir -p "$root.tmp"
  for deb in "$dir"/apt/cache/archives/*.deb; do dpkg -x "$deb" "$root.tmp"; done
  rm -rf "$root" && mv "$root.tmp" "$root"
  rm -f "$dir"/apt/cache/archives/*.deb
  # The package's manifest names the library without a path: point a copy at the unpacked one.
  sed "s#\"library_path\": *\"[^\"]*\"#\"library_path\": \"$lib/libvulkan_lvp.so\"#" \
    "$root/usr/share/vulkan/icd.d/lvp_icd.json" > "$icd"
  [ -f "$lib/libGLdispatch.so.0" ] || { echo "coopmat-lavapipe: no libGLdispatch.so.0 unpacked" >&2; exit 1; }
  grep -q VK_KHR_cooperative_matrix "$lib/libvulkan_lvp.so" ||
    { echo "coopmat-lavapipe: the fetched lavapipe has no VK_KHR_cooperative_matrix" >&2; exit 1; }
fi

if [ "${1:-}" = run ]; then
  shift
  export VK_ICD_FILENAMES="$icd" VK_LAYER_PATH="$root/usr/share/vulkan/explicit_layer.d"
  exec "$lib/ld-linux-x86-64.so.2" --library-path "$lib:/usr/lib/x86_64-linux-gnu:/lib/x86_64-linux-gnu" "$@"
fi
echo "coopmat-lavapipe: $("$lib/ld-linux-x86-64.so.2" --library-path "$lib" "$lib/libc.so.6" | head -n 1)"
echo "coopmat-lavapipe: run programs with: bash scripts/portability/coopmat-lavapipe.sh run PROGRAM ARGS..."
