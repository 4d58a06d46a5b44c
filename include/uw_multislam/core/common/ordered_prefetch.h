// Work computed ahead on worker threads and handed out in order: what lets a 2-core machine
// overlap the preparation of the next frames (enhancement, SIFT) with the odometry, loop detection
// and back-end of this one. One class for both heads:
//   - offline_slam --threads: the items are a dataset's frame numbers 0..count-1, submitted by the
//     class itself at most `ahead` beyond the one next() hands out next (images are megabytes);
//   - the odometry nodelet (~prepare_threads), drop_policy oldest: the items are the frames its
//     worker takes out of its FIFO, submitted by the caller (submit) only when they are already
//     waiting, so that a frame is never held back for a worker when frames do not back up;
//   - the odometry nodelet, drop_policy newest (Start::kNewest): every frame is submitted as it
//     arrives and a worker starts only the newest one not started, so that when the odometry
//     frees up and takes the newest frame its features are ready or under way; a frame submitted
//     supersedes the ones no worker has started (they are never started: the odometry skips
//     them, or prepares one itself), and the consumer takes one item (takeIfStarted), discarding
//     the ones before it.
//
// Hand-written because what is needed is not a plain thread pool: results in order, a bounded
// lookahead (or only the newest item started), and per-worker state (a SIFT extractor is not
// thread-safe, so each worker owns one: `work` gets the worker's number). OpenCV's parallel_for_
// and std::async give none of the three; Boost.Asio's thread_pool gives none of the last two.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <deque>
#include <exception>
#include <functional>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <type_traits>
#include <utility>
#include <vector>

#include "uw_multislam/core/common/thread_annotations.h"

namespace uw_multislam {
namespace core {

template <class T, class In = std::size_t>
class OrderedPrefetch {
 public:
  /// Work(item, worker): worker in [0, threads) (0 when computed by next() itself).
  using Work = std::function<T(In item, int worker)>;

  /// Which submitted item a free worker starts.
  enum class Start {
    kInOrder,  // the oldest not started: every item is computed
    kNewest,   // the newest not started; submit() supersedes the items not started (never started)
  };

  /// Items submitted by the caller (submit), computed by `threads` workers, handed out in the
  /// order submitted. With threads == 0 nothing runs in the background: next() computes each item
  /// in the caller (worker 0).
  OrderedPrefetch(int threads, Work work, Start start_order = Start::kInOrder)
      : ahead_(kUnbounded), newest_(start_order == Start::kNewest), work_(std::move(work)) {
    start(threads);
  }

  /// The items 0..count-1 (In = std::size_t), computed by `threads` workers in index order, at most
  /// `ahead` items beyond the one next() hands out next (ahead >= 1).
  OrderedPrefetch(std::size_t count, int threads, std::size_t ahead, Work work)
      : ahead_(ahead < 1 ? 1 : ahead), work_(std::move(work)) {
    static_assert(std::is_same<In, std::size_t>::value, "OrderedPrefetch: a count of items needs In = std::size_t");
    for (std::size_t i = 0; i < count; ++i) waiting_.emplace_back(i, i);
    submitted_ = count;
    start(threads);
  }

  ~OrderedPrefetch() {
    {
      MutexLock lock(&mutex_);
      stop_ = true;
    }
    changed_.notify_all();
    for (std::thread& t : workers_) t.join();
  }
  OrderedPrefetch(const OrderedPrefetch&) = delete;
  OrderedPrefetch& operator=(const OrderedPrefetch&) = delete;

  /// Adds an item after those submitted before; returns its number (0, 1, ... in the order
  /// submitted). Start::kNewest: the items no worker has started are superseded (never started).
  std::size_t submit(In item) {
    std::size_t number = 0;
    {
      MutexLock lock(&mutex_);
      if (newest_) {
        for (auto& w : waiting_) ready_.emplace(w.first, Slot{T{}, nullptr, false});
        waiting_.clear();
      }
      number = submitted_++;
      waiting_.emplace_back(number, std::move(item));
    }
    changed_.notify_all();
    return number;
  }

  /// Items submitted and not handed out yet.
  std::size_t pending() const {
    MutexLock lock(&mutex_);
    return submitted_ - next_out_;
  }
  bool done() const { return pending() == 0; }

  /// The next item in order; waits for it. Rethrows what `work` threw for it. Start::kInOrder only
  /// (with kNewest an item may never be computed: takeIfStarted).
  T next() {
    if (newest_) throw std::logic_error("OrderedPrefetch::next: Start::kNewest hands out by takeIfStarted");
    UniqueMutexLock lock(&mutex_);
    if (next_out_ >= submitted_) throw std::out_of_range("OrderedPrefetch::next: every item was handed out");
    const std::size_t item = next_out_++;  // written under the lock: the workers read it
    if (workers_.empty()) {
      In in = std::move(waiting_.front().second);
      waiting_.pop_front();
      lock.unlock();
      return work_(std::move(in), 0);
    }
    changed_.notify_all();  // the window moved: a worker may take another item
    mutex_.wait(changed_, [&] {
      mutex_.assertHeld();  // the predicate runs under the lock
      return ready_.count(item) > 0;
    });
    Slot slot = std::move(ready_.at(item));
    ready_.erase(item);
    lock.unlock();
    if (slot.error) std::rethrow_exception(slot.error);
    return std::move(slot.value);
  }

  /// Hands out item `number` (submit's), and discards the items before it not handed out yet: a
  /// discarded item not started is never started, one in progress is thrown away when done. Its
  /// value when a worker started it (waiting for it to finish), else nullopt: never started (or
  /// superseded), it is the caller's to compute, rather than wait until a busy worker is free.
  /// Rethrows what `work` threw for it.
  std::optional<T> takeIfStarted(std::size_t number) {
    UniqueMutexLock lock(&mutex_);
    if (number < next_out_ || number >= submitted_)
      throw std::out_of_range("OrderedPrefetch::takeIfStarted: item " + std::to_string(number) +
                              " was handed out or not submitted");
    for (; next_out_ < number; ++next_out_) discardLocked(next_out_);
    ++next_out_;
    for (auto w = waiting_.begin(); w != waiting_.end(); ++w) {
      if (w->first != number) continue;
      waiting_.erase(w);
      changed_.notify_all();
      return std::nullopt;
    }
    changed_.notify_all();
    mutex_.wait(changed_, [&] {
      mutex_.assertHeld();
      return ready_.count(number) > 0;
    });
    Slot slot = std::move(ready_.at(number));
    ready_.erase(number);
    lock.unlock();
    if (!slot.computed) return std::nullopt;
    if (slot.error) std::rethrow_exception(slot.error);
    return std::move(slot.value);
  }

  /// Whether a worker has started item `number` (under way or done) and it is not handed out.
  bool started(std::size_t number) const {
    MutexLock lock(&mutex_);
    if (number < next_out_ || number >= submitted_) return false;
    for (const auto& w : waiting_)
      if (w.first == number) return false;
    const auto r = ready_.find(number);
    return r == ready_.end() || r->second.computed;
  }

  /// Results computed and then discarded by takeIfStarted (a worker's time spent in vain).
  long discardedComputed() const {
    MutexLock lock(&mutex_);
    return discarded_computed_;
  }

 private:
  static constexpr std::size_t kUnbounded = std::numeric_limits<std::size_t>::max() / 2;
  struct Slot {
    T value{};
    std::exception_ptr error;
    bool computed = true;  // false: superseded before a worker started it (Start::kNewest)
  };

  // Item `item` (not handed out) is not wanted.
  void discardLocked(std::size_t item) REQUIRES(mutex_) {
    for (auto w = waiting_.begin(); w != waiting_.end(); ++w) {
      if (w->first != item) continue;
      waiting_.erase(w);
      return;
    }
    const auto r = ready_.find(item);
    if (r == ready_.end()) {
      unwanted_.insert(item);  // in progress: dropped when its worker is done
      return;
    }
    discarded_computed_ += r->second.computed;
    ready_.erase(r);
  }

  void start(int threads) {
    if (threads < 0) throw std::invalid_argument("OrderedPrefetch: threads < 0");
    for (int w = 0; w < threads; ++w) workers_.emplace_back([this, w] { run(w); });
  }

  void run(int worker) {
    UniqueMutexLock lock(&mutex_);
    for (;;) {
      mutex_.wait(changed_, [&] {
        mutex_.assertHeld();
        return stop_ || (!waiting_.empty() && waiting_.front().first < next_out_ + ahead_);
      });
      if (stop_) return;
      // kNewest keeps at most one item waiting (submit supersedes the others): front is back.
      const std::size_t item = waiting_.front().first;
      In in = std::move(waiting_.front().second);
      waiting_.pop_front();
      lock.unlock();
      Slot slot;
      try {
        slot.value = work_(std::move(in), worker);
      } catch (...) {
        slot.error = std::current_exception();
      }
      lock.lock();
      if (unwanted_.erase(item) > 0)
        ++discarded_computed_;
      else
        ready_.emplace(item, std::move(slot));
      changed_.notify_all();
    }
  }

  const std::size_t ahead_;
  const bool newest_ = false;  // Start::kNewest
  Work work_;
  mutable Mutex mutex_;
  std::condition_variable changed_;
  std::deque<std::pair<std::size_t, In>> waiting_
      GUARDED_BY(mutex_);                                 // submitted, not started: (number, item), in order
  std::size_t submitted_ GUARDED_BY(mutex_) = 0;          // items submitted
  std::size_t next_out_ GUARDED_BY(mutex_) = 0;           // the next item handed out
  std::map<std::size_t, Slot> ready_ GUARDED_BY(mutex_);  // done or superseded, not handed out
  std::set<std::size_t> unwanted_ GUARDED_BY(mutex_);     // discarded while in progress
  long discarded_computed_ GUARDED_BY(mutex_) = 0;
  bool stop_ GUARDED_BY(mutex_) = false;
  std::vector<std::thread> workers_;
};

}  // namespace core
}  // namespace uw_multislam
