#!/usr/bin/env bash
# One command from a fresh Debian 12 machine to a result: installs the packages, builds, and
# culls the default scene (scenes/default.json) on the GPU and the CPU reference, compared.
# Arguments are passed to `cullpipe run`, e.g. scripts/run.sh --bv obb --views 8.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
bash "$root/scripts/setup.sh"
bash "$root/scripts/build.sh"
exec "${CULLPIPE_BUILD_DIR:-$root/build}/cullpipe" run "$@"
