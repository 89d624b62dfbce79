#!/usr/bin/env bash
# Builds the libFuzzer targets (tests/fuzz) with clang (Debian 12: clang 14 and its runtimes,
# libclang-rt-14-dev, installed by setup.sh), AddressSanitizer and UBSan into
# build-fuzz/, and runs each for SECONDS (default 60) seconds from a seed corpus of the
# project's own files (and ../shared/scenes when present); fuzz_cull checks the fast CPU
# cullers against the reference. Fails on any crash, leak, sanitizer
# report, hang or unexpected exception; the failing input is left in build-fuzz/crashes/.
# usage: bash scripts/fuzz.sh [SECONDS]
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
seconds=${1:-60}
bash "$root/scripts/setup.sh"
build=$root/build-fuzz
CC=clang CXX=clang++ cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCULLPIPE_FUZZ=ON \
  -DCULLPIPE_BUILD_TESTS=OFF -DCULLPIPE_BUILD_BENCH=OFF >/dev/null
cmake --build "$build" --parallel "$(nproc)" --target fuzz_gltf fuzz_json fuzz_points fuzz_bounds fuzz_cull

# Seed corpora: inputs committed in tests/fuzz/corpus/<target> and every earlier failing input
# (tests/fuzz/regressions/<target>; CTest replays both), plus real files.
corpus=$build/corpus
rm -rf "$corpus" "$build/crashes"
mkdir -p "$corpus"/{gltf,json,points,bounds,cull} "$build/crashes"
for t in gltf json points bounds cull; do
  for dir in "$root/tests/fuzz/corpus/$t" "$root/tests/fuzz/regressions/$t"; do
    [ -d "$dir" ] && cp "$dir"/* "$corpus/$t/" 2>/dev/null || true
  done
done
cp "$root/scenes/"*.json "$root/tests/data/"*.json "$corpus/json/"
shared=$root/../shared/scenes
if [ -d "$shared" ]; then
  # Small real glTF files only (the fuzzer mutates them; large ones slow every run).
  find "$shared" \( -name '*.gltf' -o -name '*.glb' \) -size -64k -exec cp {} "$corpus/gltf/" \;
fi

status=0
for t in gltf json points bounds cull; do
  echo "fuzz: fuzz_$t for ${seconds}s"
  if ! (cd "$build/crashes" && ASAN_OPTIONS=detect_leaks=1 "$build/tests/fuzz/fuzz_$t" "$corpus/$t" \
          -max_total_time="$seconds" -timeout=10 -rss_limit_mb=4096 -max_len=65536 -print_final_stats=1 \
          2>"$build/fuzz_$t.log"); then
    echo "fuzz: fuzz_$t FAILED; log: $build/fuzz_$t.log, inputs in $build/crashes" >&2
    echo "fuzz: after the fix, copy the input to tests/fuzz/regressions/$t/ (CTest replays it from then on)" >&2
    tail -40 "$build/fuzz_$t.log" >&2
    status=1
  else
    grep -E "stat::number_of_executed_units|cov:" "$build/fuzz_$t.log" | tail -2
  fi
done
exit $status
