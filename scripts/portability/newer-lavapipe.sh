#!/usr/bin/env bash
# Fetches Mesa 25.0's lavapipe beside the build and runs programs on it.
#
# A second Vulkan driver to test and measure against, without touching the system: Mesa's
# lavapipe from Debian's bookworm-backports suite (25.0.x, Debian 13's default generation),
# downloaded and unpacked beside the build. The system's lavapipe (Mesa 22.3) stays the default.
#
#   bash scripts/portability/newer-lavapipe.sh                 # fetch and unpack once, print the variables
#   bash scripts/portability/newer-lavapipe.sh run CMD ARGS... # run one command on the newer driver, e.g.
#   bash scripts/portability/newer-lavapipe.sh run bash scripts/demo/demo.sh
#   bash scripts/portability/newer-lavapipe.sh run build/bin/spar-bench --only gemm
#
# Needs network access to deb.debian.org (apt-get download, no root). DIR (default
# build/mesa-backports) holds the apt state, the .debs and the unpacked driver.
set -euo pipefail
cd "$(dirname "$0")/../.."
dir=${DIR:-build/mesa-backports}
mkdir -p "$dir"
dir=$(cd "$dir" && pwd)
icd="$dir/lvp_icd.json"
lib="$dir/root/usr/lib/x86_64-linux-gnu"

if [ ! -f "$icd" ]; then
  mkdir -p "$dir/apt/lists/partial" "$dir/debs" "$dir/root"
  echo "deb [signed-by=/usr/share/keyrings/debian-archive-keyring.gpg] http://deb.debian.org/debian bookworm-backports main" \
    > "$dir/apt/sources.list"
  apt_opts=(-o Dir::Etc::SourceList="$dir/apt/sources.list" -o Dir::Etc::SourceParts=/dev/null
            -o Dir::State::Lists="$dir/apt/lists" -o Dir::Cache="$dir/apt/cache" -o Debug::NoLocking=1)
  mkdir -p "$dir/apt/cache/archives/partial"
  apt-get "${apt_opts[@]}" update -q >/dev/null
  (cd "$dir/debs" && apt-get "${apt_opts[@]}" download \
     mesa-vulkan-drivers/bookworm-backports libdrm2/bookworm-backports libdrm-amdgpu1/bookworm-backports) >&2  # stdout stays the program's
  for deb in "$dir"/debs/*.deb; do dpkg -x "$deb" "$dir/root"; done
  # The package's manifest names the library without a path: point a copy at the unpacked one.
  sed "s#\"library_path\": *\"[^\"]*\"#\"library_path\": \"$lib/libvulkan_lvp.so\"#" \
    "$dir/root/usr/share/vulkan/icd.d/lvp_icd.json" > "$icd"
fi

if [ "${1:-}" = run ]; then
  shift
  VK_ICD_FILENAMES="$icd" LD_LIBRARY_PATH="$lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}" exec "$@"
fi
echo "export VK_ICD_FILENAMES=$icd"
echo "export LD_LIBRARY_PATH=$lib"
echo "# then: vulkaninfo --summary | grep driverInfo   (Mesa 25.0.x)"
