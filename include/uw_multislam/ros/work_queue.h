// The bounded FIFO between a nodelet's subscriber callbacks and its one worker thread (STYLE.md
// 5: callbacks enqueue, heavy work runs on a worker with a bounded queue and an explicit,
// counted drop policy). Header-only and ROS-free, so its test needs neither ROS nor a master.
//
// Drop policy: push() on a full queue drops the OLDEST item and counts it (live, the newest
// data matters most). An optional drop handler sees each dropped item together with its
// successor (the item that now heads the queue), to hand on what must survive the drop (the
// odometry hands on the dropped frame's stamp, so its own drops never look like a time gap). pushPriority() is for the
// few items that must never be lost (e.g. a reload of stored keyframes): they are served before the bounded ones, are
// never dropped and do not count against the capacity.
//
// Selection: popSelected() lets the worker take a newer waiting item than the oldest, skipping
// (and counting) the ones before it: the odometry's bounded-latency policy (core/frontend/frame_skip.h).
//
// Shutdown: close() wakes every pop(); pop() then still returns what is queued, in order (a clean
// shutdown processes it: nothing queued is lost), and false once the queue is empty. Items pushed
// after close() are refused.
#pragma once

#include <algorithm>
#include <condition_variable>
#include <cstddef>
#include <deque>
#include <functional>
#include <mutex>
#include <stdexcept>
#include <utility>

#include "uw_multislam/core/common/ordered_prefetch.h"

namespace uw_multislam {
namespace ros_work {

template <typename T>
class BoundedWorkQueue {
 public:
  /// Called under the queue's lock for each item dropped to make room, with its successor: the
  /// oldest item left (the one just pushed when the capacity is 1). It must not touch the queue.
  using DropHandler = std::function<void(T& dropped, T& successor)>;

  /// `capacity`: the most bounded items waiting (>= 1).
  explicit BoundedWorkQueue(std::size_t capacity, DropHandler on_drop = {})
      : capacity_(capacity), on_drop_(std::move(on_drop)) {
    if (capacity < 1) throw std::invalid_argument("BoundedWorkQueue: capacity must be at least 1");
  }
  BoundedWorkQueue(const BoundedWorkQueue&) = delete;
  BoundedWorkQueue& operator=(const BoundedWorkQueue&) = delete;

  /// Enqueues `item`; when the queue is full the oldest bounded item is dropped and counted.
  /// Returns false (and drops `item`, uncounted) after close().
  bool push(T item) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (closed_) return false;
      if (items_.size() >= capacity_) {
        T oldest = std::move(items_.front());
        items_.pop_front();
        ++dropped_;
        items_.push_back(std::move(item));
        if (on_drop_) on_drop_(oldest, items_.front());
      } else {
        items_.push_back(std::move(item));
      }
      ++pushed_;
    }
    wake_.notify_one();
    return true;
  }

  /// Enqueues `item` ahead of the bounded items (after earlier priority items); never dropped.
  /// Returns false after close().
  bool pushPriority(T item) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (closed_) return false;
      priority_.push_back(std::move(item));
    }
    wake_.notify_one();
    return true;
  }

  /// Blocks until an item is available (priority items first) or the queue is closed and empty.
  /// Returns false only then.
  bool pop(T* out) {
    std::unique_lock<std::mutex> lock(mutex_);
    ++waiting_;
    wake_.wait(lock, [this] { return closed_ || !priority_.empty() || !items_.empty(); });
    --waiting_;
    std::deque<T>& from = !priority_.empty() ? priority_ : items_;
    if (from.empty()) return false;  // closed and drained
    *out = std::move(from.front());
    from.pop_front();
    ++popped_;
    return true;
  }

  /// pop() of the bounded item `select` picks: select(const std::deque<T>& waiting) returns the
  /// index of the item to take (0: the oldest, as pop()); the items before it are skipped, each
  /// handed to `on_skip(skipped, taken)` under the lock (like a drop, to hand on what must survive)
  /// and counted in skipped(). Priority items are taken first, as by pop(). Blocks like pop().
  template <typename Select, typename OnSkip>
  bool popSelected(T* out, Select select, OnSkip on_skip) {
    std::unique_lock<std::mutex> lock(mutex_);
    ++waiting_;
    wake_.wait(lock, [this] { return closed_ || !priority_.empty() || !items_.empty(); });
    --waiting_;
    if (priority_.empty() && items_.empty()) return false;  // closed and drained
    if (!priority_.empty()) {
      *out = std::move(priority_.front());
      priority_.pop_front();
    } else {
      const std::size_t take =
          std::min<std::size_t>(select(static_cast<const std::deque<T>&>(items_)), items_.size() - 1);
      for (std::size_t i = 0; i < take; ++i) on_skip(items_[i], items_[take]);
      *out = std::move(items_[take]);
      items_.erase(items_.begin(), items_.begin() + static_cast<std::ptrdiff_t>(take) + 1);
      skipped_ += static_cast<long>(take);
    }
    ++popped_;
    return true;
  }

  /// pop() without the wait: false when nothing is queued (now).
  bool tryPop(T* out) {
    std::lock_guard<std::mutex> lock(mutex_);
    std::deque<T>& from = !priority_.empty() ? priority_ : items_;
    if (from.empty()) return false;
    *out = std::move(from.front());
    from.pop_front();
    ++popped_;
    return true;
  }

  /// No more pushes; every waiting pop() wakes. What is queued is still handed out.
  void close() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      closed_ = true;
    }
    wake_.notify_all();
  }

  std::size_t capacity() const { return capacity_; }
  /// Items dropped because the queue was full.
  long dropped() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return dropped_;
  }
  /// Items waiting (bounded and priority).
  std::size_t size() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return items_.size() + priority_.size();
  }
  /// Bounded items accepted by push() (including those dropped later).
  long pushed() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return pushed_;
  }
  /// Items popSelected() passed over for a newer one.
  long skipped() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return skipped_;
  }
  /// Items handed out by pop().
  long popped() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return popped_;
  }
  /// Threads blocked in pop() right now (lets a test wait until the worker is idle).
  int waiting() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return waiting_;
  }
  bool closed() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return closed_;
  }

 private:
  const std::size_t capacity_;
  const DropHandler on_drop_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<T> items_;     // guarded by mutex_
  std::deque<T> priority_;  // guarded by mutex_
  bool closed_ = false;     // guarded by mutex_
  long dropped_ = 0;        // guarded by mutex_
  long pushed_ = 0;         // guarded by mutex_
  long popped_ = 0;         // guarded by mutex_
  long skipped_ = 0;        // guarded by mutex_
  int waiting_ = 0;         // guarded by mutex_
};

/// The worker's loop: takes the items of `queue` until it is closed and drained, and calls
/// process(item, prepared) for each in order. With `threads` > 0, up to `threads` items already
/// waiting are taken out early and `prepare`d (P(const T&)) by that many long-lived threads
/// (core::OrderedPrefetch) while the item before them is processed; an item is never waited for:
/// one taken while none is in preparation is processed at once (prepared null). Drop policy: the
/// items taken out early are the worker's, no longer the queue's to drop.
template <typename T, typename P, typename Prepare, typename Process>
void drainWithPrepareAhead(BoundedWorkQueue<T>& queue, int threads, Prepare prepare, Process process) {
  using Item = std::pair<T, P>;
  core::OrderedPrefetch<Item, T> ahead(threads, [&prepare](T item, int) {
    P p = prepare(static_cast<const T&>(item));
    return Item(std::move(item), std::move(p));
  });
  const std::size_t n = static_cast<std::size_t>(threads < 0 ? 0 : threads);
  for (;;) {
    T item;
    const bool now = ahead.pending() == 0;  // nothing in preparation: this item is processed as it is
    if (now && !queue.pop(&item)) return;   // closed and drained
    for (T next; ahead.pending() < n + (now ? 0 : 1) && queue.tryPop(&next); next = T()) ahead.submit(std::move(next));
    if (now) {
      process(item, static_cast<P*>(nullptr));
    } else {
      Item prepared = ahead.next();
      process(prepared.first, &prepared.second);
    }
  }
}

}  // namespace ros_work
}  // namespace uw_multislam
