// Work computed ahead on worker threads and handed out in order: what lets a 2-core machine
// overlap the preparation of the next frames (enhancement, SIFT) with the odometry, loop detection
// and back-end of this one. One class for both heads:
//   - offline_slam --threads: the items are a dataset's frame numbers 0..count-1, submitted by the
//     class itself at most `ahead` beyond the one next() hands out next (images are megabytes);
//   - the odometry nodelet (~prepare_threads): the items are the frames its worker takes out of its
//     FIFO, submitted by the caller (submit) only when they are already waiting, so that a frame is
//     never held back for a worker when frames do not back up.
//
// Hand-written, ~100 lines, because what is needed is not a plain thread pool: results in order, a
// bounded lookahead, and per-worker state (a SIFT extractor is not thread-safe, so each worker owns
// one: `work` gets the worker's number). OpenCV's parallel_for_ and std::async give none of the
// three; Boost.Asio's thread_pool gives none of the last two.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <deque>
#include <exception>
#include <functional>
#include <limits>
#include <map>
#include <mutex>
#include <stdexcept>
#include <thread>
#include <type_traits>
#include <utility>
#include <vector>

namespace uw_multislam {
namespace core {

template <class T, class In = std::size_t>
class OrderedPrefetch {
 public:
  /// Work(item, worker): worker in [0, threads) (0 when computed by next() itself).
  using Work = std::function<T(In item, int worker)>;

  /// Items submitted by the caller (submit), computed by `threads` workers, handed out in the
  /// order submitted. With threads == 0 nothing runs in the background: next() computes each item
  /// in the caller (worker 0).
  OrderedPrefetch(int threads, Work work) : ahead_(kUnbounded), work_(std::move(work)) { start(threads); }

  /// The items 0..count-1 (In = std::size_t), computed by `threads` workers in index order, at most
  /// `ahead` items beyond the one next() hands out next (ahead >= 1).
  OrderedPrefetch(std::size_t count, int threads, std::size_t ahead, Work work)
      : ahead_(ahead < 1 ? 1 : ahead), work_(std::move(work)) {
    static_assert(std::is_same<In, std::size_t>::value, "OrderedPrefetch: a count of items needs In = std::size_t");
    for (std::size_t i = 0; i < count; ++i) waiting_.push_back(i);
    submitted_ = count;
    start(threads);
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

  /// Adds an item after those submitted before.
  void submit(In item) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      waiting_.push_back(std::move(item));
      ++submitted_;
    }
    changed_.notify_all();
  }

  /// Items submitted and not handed out yet.
  std::size_t pending() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return submitted_ - next_out_;
  }
  bool done() const { return pending() == 0; }

  /// The next item in order; waits for it. Rethrows what `work` threw for it.
  T next() {
    std::unique_lock<std::mutex> lock(mutex_);
    if (next_out_ >= submitted_) throw std::out_of_range("OrderedPrefetch::next: every item was handed out");
    const std::size_t item = next_out_++;  // written under the lock: the workers read it
    if (workers_.empty()) {
      In in = std::move(waiting_.front());
      waiting_.pop_front();
      ++next_in_;
      lock.unlock();
      return work_(std::move(in), 0);
    }
    changed_.notify_all();  // the window moved: a worker may take another item
    changed_.wait(lock, [&] { return ready_.count(item) > 0; });
    Slot slot = std::move(ready_.at(item));
    ready_.erase(item);
    lock.unlock();
    if (slot.error) std::rethrow_exception(slot.error);
    return std::move(slot.value);
  }

 private:
  static constexpr std::size_t kUnbounded = std::numeric_limits<std::size_t>::max() / 2;
  struct Slot {
    T value{};
    std::exception_ptr error;
  };

  void start(int threads) {
    if (threads < 0) throw std::invalid_argument("OrderedPrefetch: threads < 0");
    for (int w = 0; w < threads; ++w) workers_.emplace_back([this, w] { run(w); });
  }

  void run(int worker) {
    std::unique_lock<std::mutex> lock(mutex_);
    for (;;) {
      changed_.wait(lock, [&] { return stop_ || (!waiting_.empty() && next_in_ < next_out_ + ahead_); });
      if (stop_) return;
      const std::size_t item = next_in_++;
      In in = std::move(waiting_.front());
      waiting_.pop_front();
      lock.unlock();
      Slot slot;
      try {
        slot.value = work_(std::move(in), worker);
      } catch (...) {
        slot.error = std::current_exception();
      }
      lock.lock();
      ready_.emplace(item, std::move(slot));
      changed_.notify_all();
    }
  }

  const std::size_t ahead_;
  Work work_;
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<In> waiting_;     // submitted, not started: the items next_in_, next_in_ + 1, ... (under mutex_)
  std::size_t submitted_ = 0;  // items submitted (under mutex_)
  std::size_t next_in_ = 0;    // the next item a worker takes (under mutex_)
  std::size_t next_out_ = 0;   // the next item next() hands out (under mutex_)
  std::map<std::size_t, Slot> ready_;
  bool stop_ = false;
  std::vector<std::thread> workers_;
};

}  // namespace core
}  // namespace uw_multislam
