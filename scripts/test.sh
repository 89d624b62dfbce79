#!/usr/bin/env bash
# One command from a fresh Debian 12 machine to a passing test suite: installs the packages,
# builds with warnings as errors, and runs every test with CTest. GPU tests run on the device
# CULLPIPE_DEVICE names (default: first GPU, else lavapipe) with Vulkan validation on.
# With --sanitize, also builds into build-asan/ with AddressSanitizer + UBSan and runs the
# suite again there.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
bash "$root/scripts/setup.sh"
bash "$root/scripts/build.sh" -DCULLPIPE_WERROR=ON
build=${CULLPIPE_BUILD_DIR:-$root/build}
ctest --test-dir "$build" --output-on-failure
# The installed package works for a consumer: install, build examples/engine against it with
# find_package(cullpipe), and run it (its own device, culling recorded into its command
# buffer, checked against the CPU reference, the culled scene drawn to a PNG).
rm -rf "$build/install" "$build/example"
cmake --install "$build" --prefix "$build/install" >/dev/null
# Every installed header compiles on its own include path alone (none needs a header that was
# not installed), without warnings.
mkdir -p "$build/example"
(cd "$build/install/include" && find cullpipe \( -name '*.hpp' -o -name '*.h' \) | sort | sed 's/.*/#include <&>/') >"$build/example/every_header.cpp"
c++ -std=c++20 -fsyntax-only -Wall -Wextra -Wpedantic -Werror -I"$build/install/include" "$build/example/every_header.cpp"
cmake -S "$root/examples/engine" -B "$build/example" -G Ninja -DCMAKE_PREFIX_PATH="$build/install" -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build "$build/example"
(cd "$build/example" && ./engine_example)
if [ "${1:-}" = "--sanitize" ]; then
  CULLPIPE_BUILD_DIR=$root/build-asan CMAKE_BUILD_TYPE=RelWithDebInfo \
    bash "$root/scripts/build.sh" -DCULLPIPE_WERROR=ON -DCULLPIPE_SANITIZE=ON -DCULLPIPE_BUILD_BENCH=OFF
  # The Vulkan loader unloads the driver and layer at vkDestroyInstance, after which leak
  # reports from them lose their module names; preloading keeps them mapped, so the
  # suppressions in tests/lsan.supp (driver and layer leaks only) can match.
  libdir=/usr/lib/$(gcc -print-multiarch)
  preload="$(gcc -print-file-name=libasan.so)"
  for lib in libvulkan_lvp.so libVkLayer_khronos_validation.so; do
    [ -f "$libdir/$lib" ] && preload="$preload $libdir/$lib"
  done
  LD_PRELOAD="$preload" \
  ASAN_OPTIONS=halt_on_error=1:detect_leaks=1 \
  LSAN_OPTIONS=suppressions=$root/tests/lsan.supp:print_suppressions=0 \
  UBSAN_OPTIONS=halt_on_error=1:print_stacktrace=1 \
    ctest --test-dir "$root/build-asan" --output-on-failure
fi
