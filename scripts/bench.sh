#!/usr/bin/env bash
# The comparison harness end to end: installs the packages (plus gnuplot for the plots),
# builds, and runs cullpipe-bench with every method on 10^3..16*10^6 objects. Writes
# bench/results/cullpipe-bench.{csv,json} and bench/results/cullpipe-bench-{aabb,obb,sphere}.png.
# Arguments are passed to cullpipe-bench, e.g. scripts/bench.sh --sizes 1e4,1e6 --bv aabb.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
bash "$root/scripts/setup.sh"
if ! command -v gnuplot >/dev/null; then
  if [ "$(id -u)" -eq 0 ]; then apt-get install -y --no-install-recommends gnuplot-nox; else sudo apt-get install -y --no-install-recommends gnuplot-nox; fi
fi
bash "$root/scripts/build.sh"
out="$root/bench/results"
mkdir -p "$out"
exec "${CULLPIPE_BUILD_DIR:-$root/build}/bench/cullpipe-bench" --csv "$out/cullpipe-bench.csv" --json "$out/cullpipe-bench.json" \
  --plot "$out/cullpipe-bench" "$@"
