#include "cull/thread_pool.hpp"

#include <algorithm>
#include <chrono>
#include <stdexcept>

#if defined(__SSE__)
#include <xmmintrin.h>
#endif

namespace cullpipe::fast {

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

void ThreadPool::run_tasks(std::size_t generation, const TaskRef& task, std::size_t tasks) {
  // Only the tasks of `generation`: a worker that woke late, after the caller had finished
  // that generation and started the next, must not run the next one's tasks in the float
  // mode it loaded for this one. Claims are lock free: with a mutex per claim, two threads
  // claiming at once put one to sleep in the kernel (a futex wait and wake, tens of
  // microseconds on a virtual machine, a large part of a hierarchical pass).
  const std::uint64_t mine = (std::uint64_t(generation) & kTaskMask) << 32;
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

void ThreadPool::worker_loop() {
  std::size_t seen = 0;
  std::unique_lock lock(mutex_);
  for (;;) {
    lock.unlock();
    spin_until([&] { return stop_.load(std::memory_order_relaxed) || generation_.load(std::memory_order_relaxed) != seen; });
    lock.lock();
    wake_.wait(lock, [&] { return stop_ || generation_ != seen; });
    if (stop_) return;
    seen = generation_;
    ++busy_;
    // (no task_ once the caller has finished this generation: nothing left to run)
    const TaskRef task = task_ ? *task_ : TaskRef::none();
    const std::size_t tasks = task_ ? task_count_ : 0;
#if defined(__SSE__)
    const unsigned own_mode = _mm_getcsr();
    _mm_setcsr(fp_mode_);
#endif
    lock.unlock();
    run_tasks(seen, task, tasks);
#if defined(__SSE__)
    _mm_setcsr(own_mode);
#endif
    lock.lock();
    if (--busy_ == 0) done_.notify_all();
  }
}

void ThreadPool::parallel_for(std::size_t tasks, TaskRef task) {
  if (tasks == 0) return;
  if (tasks > kTaskMask) throw std::length_error("ThreadPool::parallel_for: more than 2^32 - 1 tasks");
  if (workers_.empty() || tasks == 1) {
    for (std::size_t t = 0; t < tasks; ++t) task(t);
    return;
  }
  std::size_t generation = 0;
  {
    std::lock_guard lock(mutex_);
    task_ = &task;
    task_count_ = tasks;
#if defined(__SSE__)
    fp_mode_ = _mm_getcsr();
#endif
    error_ = nullptr;
    generation = ++generation_ & kTaskMask;  // (the claims carry the low 32 bits)
    claim_.store(std::uint64_t(generation) << 32, std::memory_order_release);
  }
  wake_.notify_all();
  run_tasks(generation, task, tasks);
  spin_until([&] { return busy_.load(std::memory_order_relaxed) == 0; });
  std::unique_lock lock(mutex_);
  // Every task has been taken; wait for workers still running one (or about to look).
  done_.wait(lock, [&] { return busy_ == 0; });
  task_ = nullptr;
  task_count_ = 0;
  if (error_) {
    std::exception_ptr e = error_;
    error_ = nullptr;
    std::rethrow_exception(e);
  }
}

}  // namespace cullpipe::fast
