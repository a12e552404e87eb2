#!/usr/bin/env bash
# Installs the Debian 12 packages the project builds, tests and runs with.
# Needs root or sudo. Safe to run again: apt-get skips what is already there.
set -euo pipefail
packages=(
  build-essential cmake pkg-config
  libvulkan-dev vulkan-tools mesa-vulkan-drivers vulkan-validationlayers glslang-tools
  libglm-dev libopenimageio-dev openimageio-tools libpng-dev
  libgtest-dev nlohmann-json3-dev libcli11-dev libfmt-dev zlib1g-dev libicu-dev fonts-dejavu-core
  pybind11-dev python3-dev
  chromium  # tests open the render page (index.html) in a real browser, headless
  opencv-doc  # real footage for the tests: vtest.avi (people walking), graf1/graf3.png (one wall, two views)
  ffmpeg
  python3 python3-numpy python3-torch python3-yaml python3-pytest python3-pil libopenblas0-pthread
  clang-14 libclang-rt-14-dev ninja-build  # the sanitized build (.ci/test-sanitized.sh) and the fuzzer
)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all packages present"
  exit 0
fi
sudo=""
if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
echo "install-deps: installing ${missing[*]}"
$sudo apt-get update -q
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends "${missing[@]}"
