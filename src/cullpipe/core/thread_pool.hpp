#pragma once
#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <mutex>
#include <thread>
#include <vector>

namespace cullpipe {

/// A non-owning reference to a callable taking a task index (like C++26 std::function_ref):
/// no allocation, so a pass per frame stays allocation-free. The callable must outlive it.
class TaskRef {
 public:
  template <class F>
  TaskRef(F& f)
      : object_(&f), call_([](void* o, std::size_t t) { (*static_cast<F*>(o))(t); }) {}  // NOLINT: implicit by design
  void operator()(std::size_t t) const { call_(object_, t); }
  /// A task that does nothing.
  static TaskRef none() { return TaskRef(); }

 private:
  TaskRef() : object_(nullptr), call_([](void*, std::size_t) {}) {}
  TaskRef(void* object, void (*call)(void*, std::size_t)) : object_(object), call_(call) {}
  friend class ThreadPool;  // (copies the two pointers into its own atomics and back)
  void* object_;
  void (*call_)(void*, std::size_t);
};

/// A fixed set of worker threads that run the tasks of one parallel_for at a time. The calling
/// thread works too, so a pool of N threads starts N - 1 workers; a pool of 1 runs everything
/// on the caller. Tasks are handed out one at a time from a shared counter, so uneven tasks
/// balance themselves. Tasks run with the caller's floating-point mode (on x86, its MXCSR:
/// flush-to-zero, denormals-are-zero, rounding), so a result does not depend on which thread
/// ran it. After a parallel_for the workers (and, while it waits for them, the caller) spin
/// for up to 50 microseconds before they sleep, so the next call finds them awake; an awake
/// pool hands a call to its workers and takes it back without a lock (thread_pool.cpp). Not
/// reentrant: call parallel_for from one thread at a time.
class ThreadPool {
 public:
  /// threads = 0: std::thread::hardware_concurrency() (at least 1).
  explicit ThreadPool(unsigned threads = 0);
  ~ThreadPool();
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  unsigned size() const { return static_cast<unsigned>(workers_.size()) + 1; }
  /// Inside a task: which of the pool's threads runs it, 0 (the caller of parallel_for) to
  /// size() - 1, so that a task may use per-thread scratch. Outside the pool's workers, 0.
  unsigned thread_index() const;

  /// Runs task(t) for t = 0..tasks-1 across the pool and returns when all have finished.
  /// The first exception thrown by a task is rethrown here (the remaining tasks still run).
  void parallel_for(std::size_t tasks, TaskRef task);
  template <class F>
  void parallel_for(std::size_t tasks, F&& task) {
    parallel_for(tasks, TaskRef(task));
  }

 private:
  void worker_loop();
  void stop_workers();  // wakes, stops and joins the workers
  void run_tasks(std::uint64_t generation, const TaskRef& task, std::size_t tasks);

  std::vector<std::thread> workers_;
  // A call is published like a seqlock: the caller makes generation_ odd, writes the call
  // (job_*), then makes it even; a worker reads the call between two reads of the same even
  // generation. Workers count themselves in busy_ before they claim a task of it, and the
  // caller returns only when busy_ is 0 again, so no task runs after its call returned.
  // (Each of generation_ with the call, claim_ and busy_ on a cache line of its own: the caller
  // waiting on busy_ must not take the claims' line from a worker claiming its next task.)
  alignas(64) std::atomic<std::uint64_t> generation_ = 0;
  std::atomic<void*> job_object_ = nullptr;
  std::atomic<void (*)(void*, std::size_t)> job_call_ = nullptr;
  std::atomic<std::size_t> job_tasks_ = 0;
  std::atomic<std::uint32_t> job_fp_mode_ = 0;  // the caller's MXCSR (x86)
  // The generation's low 32 bits over the next task to claim, taken by compare-and-swap: a
  // thread claims a task of its own generation only, and never waits on a lock to claim one.
  static constexpr std::uint64_t kTaskMask = 0xffffffffu;
  alignas(64) std::atomic<std::uint64_t> claim_ = 0;
  alignas(64) std::atomic<unsigned> busy_ = 0;  // workers inside a call
  // Sleeping: workers wait on wake_ (counted in sleepers_), the caller on done_ (caller_waits_).
  alignas(64) std::mutex mutex_;
  std::condition_variable wake_, done_;
  std::atomic<unsigned> sleepers_ = 0;
  std::atomic<bool> caller_waits_ = false;
  std::atomic<bool> stop_ = false;
  std::exception_ptr error_;  // under mutex_
};

}  // namespace cullpipe
