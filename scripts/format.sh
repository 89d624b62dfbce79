#!/usr/bin/env bash
# Formats every C++ source in src/cullpipe/, tests/, bench/ and examples/ as .clang-format says (the
# test suite's check_format fails on any file this would change).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
format=$(command -v clang-format-14 || command -v clang-format)
cd "$root"
find src tests bench examples \( -path tests/fuzz/corpus -o -path tests/fuzz/regressions -o -path tests/data \) -prune \
  -o \( -name '*.cpp' -o -name '*.hpp' -o -name '*.inl' -o -name '*.h' \) -print0 | xargs -0 "$format" -i --style=file
