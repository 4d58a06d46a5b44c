// Work computed ahead on worker threads and handed out in order: what lets a 2-core machine
// overlap the extraction of the next frames with the odometry, loop detection and back-end of
// this one (offline_slam --threads, issue 19 item 3).
//
// Hand-written, ~80 lines, because what is needed is not a plain thread pool: results in index
// order, a bounded lookahead (images are megabytes), and per-worker state (a SIFT extractor is
// not thread-safe, so each worker owns one: `work` gets the worker's number). OpenCV's
// parallel_for_ and std::async give none of the three; Boost.Asio's thread_pool gives none of
// the last two.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <exception>
#include <functional>
#include <map>
#include <mutex>
#include <stdexcept>
#include <thread>
#include <utility>
#include <vector>

namespace uw_multislam {
namespace core {

template <class T>
class OrderedPrefetch {
 public:
  /// Work(item, worker): item in [0, count), worker in [0, threads).
  using Work = std::function<T(std::size_t item, int worker)>;

  /// `threads` workers compute items in index order, at most `ahead` items beyond the one next()
  /// hands out next (ahead >= 1). With threads == 0 nothing runs in the background: next()
  /// computes each item in the caller (worker 0).
  OrderedPrefetch(std::size_t count, int threads, std::size_t ahead, Work work)
      : count_(count), ahead_(ahead < 1 ? 1 : ahead), work_(std::move(work)) {
    if (threads < 0) throw std::invalid_argument("OrderedPrefetch: threads < 0");
    for (int w = 0; w < threads; ++w) workers_.emplace_back([this, w] { run(w); });
  }
  ~OrderedPrefetch() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    changed_.notify_all();
    for (std::thread& t : workers_) t.join();
  }
  OrderedPrefetch(const OrderedPrefetch&) = delete;
  OrderedPrefetch& operator=(const OrderedPrefetch&) = delete;

  bool done() const { return next_out_ >= count_; }

  /// The next item in index order; waits for it. Rethrows what `work` threw for it.
  T next() {
    if (done()) throw std::out_of_range("OrderedPrefetch::next: every item was handed out");
    if (workers_.empty()) return work_(next_out_++, 0);
    std::unique_lock<std::mutex> lock(mutex_);
    const std::size_t item = next_out_++;  // written under the lock: the workers read it
    changed_.notify_all();  // the window moved: a worker may take another item
    changed_.wait(lock, [&] { return ready_.count(item) > 0; });
    Slot slot = std::move(ready_.at(item));
    ready_.erase(item);
    lock.unlock();
    if (slot.error) std::rethrow_exception(slot.error);
    return std::move(slot.value);
  }

 private:
  struct Slot {
    T value{};
    std::exception_ptr error;
  };

  void run(int worker) {
    std::unique_lock<std::mutex> lock(mutex_);
    for (;;) {
      changed_.wait(lock, [&] { return stop_ || (next_in_ < count_ && next_in_ < next_out_ + ahead_); });
      if (stop_) return;
      const std::size_t item = next_in_++;
      lock.unlock();
      Slot slot;
      try {
        slot.value = work_(item, worker);
      } catch (...) {
        slot.error = std::current_exception();
      }
      lock.lock();
      ready_.emplace(item, std::move(slot));
      changed_.notify_all();
    }
  }

  const std::size_t count_;
  const std::size_t ahead_;
  Work work_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::size_t next_in_ = 0;  // the next item a worker takes (under mutex_)
  std::size_t next_out_ = 0;  // the next item next() hands out (written under mutex_)
  std::map<std::size_t, Slot> ready_;
  bool stop_ = false;
  std::vector<std::thread> workers_;
};

}  // namespace core
}  // namespace uw_multislam
