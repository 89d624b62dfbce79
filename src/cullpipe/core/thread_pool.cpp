#include "cullpipe/core/thread_pool.hpp"

#include <algorithm>
#include <chrono>
#include <stdexcept>
#include <utility>

#if defined(__SSE__)
#include <xmmintrin.h>
#endif

namespace cullpipe {

namespace {
// The pool whose worker this thread is, and its index there (workers only).
thread_local const ThreadPool* tls_pool = nullptr;
thread_local unsigned tls_index = 0;
}  // namespace

ThreadPool::ThreadPool(unsigned threads) {
  if (threads == 0) threads = std::max(1u, std::thread::hardware_concurrency());
  workers_.reserve(threads - 1);
  try {
    for (unsigned t = 1; t < threads; ++t)
      workers_.emplace_back([this, t] {
        tls_pool = this;
        tls_index = t;
        worker_loop();
      });
  } catch (...) {  // a thread could not start: stop and join the ones that did, then report it
    stop_workers();
    throw;
  }
}

void ThreadPool::stop_workers() {
  {
    std::lock_guard lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  for (std::thread& w : workers_) w.join();
}

ThreadPool::~ThreadPool() { stop_workers(); }

unsigned ThreadPool::thread_index() const { return tls_pool == this ? tls_index : 0u; }

void ThreadPool::run_tasks(std::uint64_t generation, const TaskRef& task, std::size_t tasks) {
  // Only the tasks of `generation`: a worker that read a call late, after the caller had
  // finished it and started the next, must not run the next one's tasks with this one's task
  // and float mode. Claims are lock free: with a mutex per claim, two threads claiming at
  // once put one to sleep in the kernel (a futex wait and wake, tens of microseconds on a
  // virtual machine, a large part of a hierarchical pass).
  const std::uint64_t mine = (generation & kTaskMask) << 32;
  std::uint64_t word = claim_.load(std::memory_order_acquire);
  for (;;) {
    if ((word & ~kTaskMask) != mine || (word & kTaskMask) >= tasks) return;
    if (!claim_.compare_exchange_weak(word, word + 1, std::memory_order_acq_rel, std::memory_order_acquire)) continue;
    try {
      task(static_cast<std::size_t>(word & kTaskMask));
    } catch (...) {
      std::lock_guard lock(mutex_);
      if (!error_) error_ = std::current_exception();
    }
    word = claim_.load(std::memory_order_acquire);
  }
}

namespace {

/// Spins until done() or about kSpin has passed: a pass of several parallel_for calls (or the
/// next frame's pass) finds the threads awake instead of paying a sleep and wake-up each
/// (tens of microseconds on a virtual machine, a large part of a hierarchical pass).
template <class Done>
bool spin_until(Done done) {
  constexpr auto kSpin = std::chrono::microseconds(50);
  const auto start = std::chrono::steady_clock::now();
  for (unsigned i = 1;; ++i) {
    if (done()) return true;
#if defined(__SSE__)
    _mm_pause();
#endif
    if (i % 64 == 0 && std::chrono::steady_clock::now() - start > kSpin) return done();
  }
}

}  // namespace

// The hand-over takes no lock while the threads are awake: under a mutex (the caller publishing
// a call, each worker reading it and leaving it, the caller collecting them) a call would move
// the mutex's cache line between the cores four times or more. The mutex is left to sleeping,
// waking and errors.
void ThreadPool::worker_loop() {
  std::uint64_t seen = 0;  // the last generation this worker ran
  auto published = [&](std::uint64_t g) { return g != seen && (g & 1u) == 0; };
  for (;;) {
    std::uint64_t g = 0;
    auto ready = [&] {
      g = generation_.load(std::memory_order_acquire);
      return stop_.load(std::memory_order_relaxed) || published(g);
    };
    if (!spin_until(ready)) {
      std::unique_lock lock(mutex_);
      // Counted before the generation is read again (both sequentially consistent): either
      // the caller sees a sleeper and notifies under the mutex, or this read sees its call.
      sleepers_.fetch_add(1);
      wake_.wait(lock, [&] {
        g = generation_.load();
        return stop_.load() || published(g);
      });
      sleepers_.fetch_sub(1);
    }
    if (stop_.load()) return;
    // Counted in busy_ before claiming a task: a claim (acq_rel, on the caller's claim word)
    // orders this count before the caller's wait for busy_ == 0, so the caller does not
    // return (and its task does not end) while this worker runs one of its tasks. A worker
    // late for a finished call claims nothing: the claim word says all are taken.
    busy_.fetch_add(1);
    const TaskRef task(job_object_.load(std::memory_order_relaxed), job_call_.load(std::memory_order_relaxed));
    const std::size_t tasks = job_tasks_.load(std::memory_order_relaxed);
    [[maybe_unused]] const std::uint32_t fp_mode = job_fp_mode_.load(std::memory_order_relaxed);
    std::atomic_thread_fence(std::memory_order_acquire);
    if (generation_.load() == g) {  // a whole call, not one half rewritten
      seen = g;
#if defined(__SSE__)
      const unsigned own_mode = _mm_getcsr();
      _mm_setcsr(fp_mode);
#endif
      run_tasks(g, task, tasks);
#if defined(__SSE__)
      _mm_setcsr(own_mode);
#endif
    }
    // Leaving; the caller, if it sleeps, is woken (the same pairing as sleepers_).
    if (busy_.fetch_sub(1) == 1 && caller_waits_.load()) {
      std::lock_guard lock(mutex_);
      done_.notify_all();
    }
  }
}

void ThreadPool::parallel_for(std::size_t tasks, TaskRef task) {
  if (tasks == 0) return;
  if (tasks > kTaskMask) throw std::length_error("ThreadPool::parallel_for: more than 2^32 - 1 tasks");
  if (workers_.empty() || tasks == 1) {
    std::exception_ptr first;  // (the remaining tasks still run, as on several threads)
    for (std::size_t t = 0; t < tasks; ++t) try {
        task(t);
      } catch (...) {
        if (!first) first = std::current_exception();
      }
    if (first) std::rethrow_exception(first);
    return;
  }
  // Publish the call: odd while it is written, even once whole.
  const std::uint64_t writing = generation_.load(std::memory_order_relaxed) + 1, generation = writing + 1;
  generation_.store(writing);
  std::atomic_thread_fence(std::memory_order_release);
  job_object_.store(task.object_, std::memory_order_relaxed);
  job_call_.store(task.call_, std::memory_order_relaxed);
  job_tasks_.store(tasks, std::memory_order_relaxed);
#if defined(__SSE__)
  job_fp_mode_.store(_mm_getcsr(), std::memory_order_relaxed);
#endif
  claim_.store((generation & kTaskMask) << 32, std::memory_order_relaxed);
  generation_.store(generation);
  if (sleepers_.load() != 0) {
    std::lock_guard lock(mutex_);
    wake_.notify_all();
  }
  run_tasks(generation, task, tasks);
  // Every task has been claimed; wait for the workers still running one (or reading the call).
  if (!spin_until([&] { return busy_.load() == 0; })) {
    std::unique_lock lock(mutex_);
    caller_waits_.store(true);
    done_.wait(lock, [&] { return busy_.load() == 0; });
    caller_waits_.store(false);
  }
  std::exception_ptr e;
  {
    std::lock_guard lock(mutex_);
    e = std::exchange(error_, nullptr);
  }
  if (e) std::rethrow_exception(e);
}

}  // namespace cullpipe
