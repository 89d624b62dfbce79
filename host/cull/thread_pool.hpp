#pragma once
#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <mutex>
#include <thread>
#include <vector>

namespace cullpipe::fast {

/// A non-owning reference to a callable taking a task index (like C++26 std::function_ref):
/// no allocation, so a pass per frame stays allocation-free. The callable must outlive it.
class TaskRef {
 public:
  template <class F>
  TaskRef(F& f) : object_(&f), call_([](void* o, std::size_t t) { (*static_cast<F*>(o))(t); }) {}  // NOLINT: implicit by design
  void operator()(std::size_t t) const { call_(object_, t); }
  /// A task that does nothing.
  static TaskRef none() { return TaskRef(); }

 private:
  TaskRef() : object_(nullptr), call_([](void*, std::size_t) {}) {}
  void* object_;
  void (*call_)(void*, std::size_t);
};

/// A fixed set of worker threads that run the tasks of one parallel_for at a time. The calling
/// thread works too, so a pool of N threads starts N - 1 workers; a pool of 1 runs everything
/// on the caller. Tasks are handed out one at a time from a shared counter, so uneven tasks
/// balance themselves. Tasks run with the caller's floating-point mode (on x86, its MXCSR:
/// flush-to-zero, denormals-are-zero, rounding), so a result does not depend on which thread
/// ran it. After a parallel_for the workers (and, while it waits for them, the caller) spin
/// for up to 50 microseconds before they sleep, so the next call finds them awake. Not
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
  void run_tasks(std::size_t generation, const TaskRef& task, std::size_t tasks);

  std::vector<std::thread> workers_;
  std::mutex mutex_;
  std::condition_variable wake_, done_;
  const TaskRef* task_ = nullptr;
  std::size_t task_count_ = 0;
  // The generation's low 32 bits over the next task to claim, taken by compare-and-swap: a
  // thread claims a task of its own generation only, and never waits on a lock to claim one.
  static constexpr std::uint64_t kTaskMask = 0xffffffffu;
  std::atomic<std::uint64_t> claim_ = 0;
  // Written under mutex_; atomic so that threads may spin on them before they sleep.
  std::atomic<std::size_t> generation_ = 0;  // bumped per parallel_for
  std::atomic<unsigned> busy_ = 0;           // workers inside the current generation
  std::exception_ptr error_;
  std::uint32_t fp_mode_ = 0;  // the caller's MXCSR for this parallel_for (x86)
  std::atomic<bool> stop_ = false;
};

}  // namespace cullpipe::fast
