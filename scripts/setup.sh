#!/usr/bin/env bash
# Installs every Debian 12 package cullpipe needs to build, test and benchmark.
# Idempotent: packages already present are skipped. Needs root or sudo.
set -euo pipefail

packages=(
  build-essential cmake ninja-build pkg-config
  mesa-vulkan-drivers libvulkan-dev vulkan-validationlayers vulkan-tools
  glslang-tools libglm-dev libtinygltf-dev nlohmann-json3-dev libcli11-dev libstb-dev
  libmeshoptimizer-dev libgtest-dev libgmock-dev libbenchmark-dev python3 clang libclang-rt-14-dev clang-format
)

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#packages[@]} packages present"
  exit 0
fi

sudo_cmd=()
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "setup: need root or sudo to install: ${missing[*]}" >&2; exit 1; }
  sudo_cmd=(sudo)
fi
echo "setup: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
"${sudo_cmd[@]}" apt-get update -qq
"${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
echo "setup: done"
