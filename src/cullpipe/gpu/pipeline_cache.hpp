#pragma once
// Compute pipelines built on first use, one per key: a key names one variant of a shader (the
// specialization constants it is built with), so a pass asks for what it needs by name.
#include <map>
#include <memory>

#include "cullpipe/vulkan/compute_pipeline.hpp"

namespace cullpipe::gpu::detail {

template <class Key>
class PipelineCache {
 public:
  /// The pipeline for `key`, built by `build()` (returning std::unique_ptr<vulkan::ComputePipeline>)
  /// the first time; if building throws, nothing is cached and the next call tries again.
  template <class Build>
  const vulkan::ComputePipeline& get(const Key& key, Build&& build) {
    auto found = pipelines_.find(key);
    if (found == pipelines_.end()) found = pipelines_.emplace(key, build()).first;
    return *found->second;
  }

 private:
  std::map<Key, std::unique_ptr<vulkan::ComputePipeline>> pipelines_;
};

}  // namespace cullpipe::gpu::detail
