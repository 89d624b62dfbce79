#pragma once
// The GPU test fixture shared by the GPU test executables: one Vulkan context with validation
// and synchronization validation on for the whole process (any message fails the test that
// caused it, and every test ends by checking none was reported), and one culler of type
// Culler on it.
#include <gtest/gtest.h>

#include <cstdio>
#include <memory>
#include <string_view>

#include "cullpipe/vulkan/context.hpp"

namespace cullpipe::test {

template <class Culler>
class GpuTestEnvironment : public ::testing::Environment {
 public:
  static inline std::unique_ptr<vulkan::Context> context;
  static inline std::unique_ptr<Culler> culler;
  void SetUp() override {
    vulkan::ContextOptions options;
    options.validation = true;
    options.on_message = [](std::string_view m) { ADD_FAILURE() << m; };
    context = std::make_unique<vulkan::Context>(options);
    culler = std::make_unique<Culler>(*context);
    std::printf("device: %s (%s)\n", context->info().name.c_str(), context->info().driver.c_str());
  }
  void TearDown() override {
    culler.reset();
    context.reset();
  }
};

template <class Culler>
class GpuTest : public ::testing::Test {
 protected:
  Culler& culler() { return *GpuTestEnvironment<Culler>::culler; }
  void TearDown() override { EXPECT_EQ(GpuTestEnvironment<Culler>::context->validation_message_count(), 0u); }
};

}  // namespace cullpipe::test
