#pragma once
// Shared by the fuzz targets: writing an input to a private temporary file (for loaders that
// take a path), and the rule for exceptions. A parser of outside input may reject it only with
// InputError (bad content) or std::length_error / std::bad_alloc (too large); anything else
// escaping, or a crash, hang or sanitizer report, is a bug the fuzzer reports.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <new>
#include <stdexcept>
#include <string>

#include "cullpipe/scene/scene.hpp"

namespace cullpipe::fuzz {

/// A directory of this process's own, removed at exit.
inline const std::filesystem::path& temp_dir() {
  static const std::filesystem::path dir = [] {
    std::filesystem::path d = std::filesystem::temp_directory_path() / ("cullpipe_fuzz_" + std::to_string(::getpid()));
    std::filesystem::create_directories(d);
    std::atexit([] {
      std::error_code ec;
      std::filesystem::remove_all(temp_dir(), ec);
    });
    return d;
  }();
  return dir;
}

inline std::string write_temp(const std::uint8_t* data, std::size_t size, const std::string& name) {
  const std::filesystem::path p = temp_dir() / name;
  std::ofstream(p, std::ios::binary | std::ios::trunc)
      .write(reinterpret_cast<const char*>(data), std::streamsize(size));
  return p.string();
}

/// Runs `body`; accepts the documented rejections, aborts on anything else.
template <class F>
void expect_clean(F&& body) {
  try {
    body();
  } catch (const InputError&) {
  } catch (const std::length_error&) {
  } catch (const std::bad_alloc&) {
  } catch (const std::exception& e) {
    std::fprintf(stderr, "unexpected exception: %s\n", e.what());
    std::abort();
  }
}

}  // namespace cullpipe::fuzz
