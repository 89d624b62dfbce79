#include "cull/thread_pool.hpp"

#include <algorithm>
#include <chrono>

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

void ThreadPool::run_tasks(std::size_t generation) {
  std::unique_lock lock(mutex_);
  // Only the tasks of `generation`: a worker that woke late, after the caller had finished
  // that generation and started the next, must not run the next one's tasks in the float
  // mode it loaded for this one.
  while (generation_ == generation && next_task_ < task_count_) {
    const std::size_t t = next_task_++;
    const TaskRef task = *task_;
    lock.unlock();
    try {
      task(t);
    } catch (...) {
      lock.lock();
      if (!error_) error_ = std::current_exception();
      continue;
    }
    lock.lock();
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
#if defined(__SSE__)
    const unsigned own_mode = _mm_getcsr();
    _mm_setcsr(fp_mode_);
#endif
    lock.unlock();
    run_tasks(seen);
#if defined(__SSE__)
    _mm_setcsr(own_mode);
#endif
    lock.lock();
    if (--busy_ == 0) done_.notify_all();
  }
}

void ThreadPool::parallel_for(std::size_t tasks, TaskRef task) {
  if (tasks == 0) return;
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
    next_task_ = 0;
    error_ = nullptr;
    generation = ++generation_;
  }
  wake_.notify_all();
  run_tasks(generation);
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
