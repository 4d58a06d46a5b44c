// The bounded FIFO between producers and one worker thread (callbacks enqueue, heavy work runs on a
// worker with a bounded queue and an explicit, counted drop policy): the nodelets' subscriber
// callbacks and their worker, and the session worker's work items (core/session/session_worker.h).
// Header-only; its test needs gtest and threads only.
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
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <deque>
#include <exception>
#include <functional>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "uw_multislam/core/common/ordered_prefetch.h"
#include "uw_multislam/core/common/thread_annotations.h"

namespace uw_multislam {
namespace core {

/// popSelected()'s choice: the item to take, and how many of the oldest before it count as dropped.
struct Selection {
  std::size_t take = 0;
  std::size_t dropped = 0;
  /// Set: take nothing yet; wait until an item is pushed, the queue is closed or this time has
  /// come, then select again (the selector must stop asking, e.g. once its deadline has passed).
  std::optional<std::chrono::steady_clock::time_point> hold_until = std::nullopt;
};

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
      MutexLock lock(&mutex_);
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
      MutexLock lock(&mutex_);
      if (closed_) return false;
      priority_.push_back(std::move(item));
    }
    wake_.notify_one();
    return true;
  }

  /// Blocks until an item is available (priority items first) or the queue is closed and empty.
  /// Returns false only then.
  bool pop(T* out) {
    MutexLock lock(&mutex_);
    ++waiting_;
    mutex_.wait(wake_, [this] {
      mutex_.assertHeld();  // the predicate runs under the lock
      return closed_ || !priority_.empty() || !items_.empty();
    });
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
  /// `select` may also return a Selection: its first `dropped` items (of those before `take`) are
  /// counted in dropped() rather than skipped() (passed over without a choice, like a full queue's drop),
  /// and with hold_until set nothing is taken yet: the worker waits for the next item (or a close,
  /// or that time) and `select` chooses again; a close ends the hold (what is queued is still handed out).
  template <typename Select, typename OnSkip>
  bool popSelected(T* out, Select select, OnSkip on_skip) {
    MutexLock lock(&mutex_);
    ++waiting_;
    mutex_.wait(wake_, [this] {
      mutex_.assertHeld();  // the predicate runs under the lock
      return closed_ || !priority_.empty() || !items_.empty();
    });
    --waiting_;
    if (priority_.empty() && items_.empty()) return false;  // closed and drained
    if (!priority_.empty()) {
      *out = std::move(priority_.front());
      priority_.pop_front();
    } else {
      Selection s;
      for (;;) {
        if constexpr (std::is_same<decltype(select(items_)), Selection>::value)
          s = select(static_cast<const std::deque<T>&>(items_));
        else
          s.take = select(static_cast<const std::deque<T>&>(items_));
        if (!s.hold_until || closed_) break;
        const long pushed = pushed_;
        ++holds_;
        mutex_.waitUntil(wake_, *s.hold_until, [&] {
          mutex_.assertHeld();
          return closed_ || pushed_ != pushed || !priority_.empty();
        });
        if (!priority_.empty()) {  // served first, as by pop(); the bounded items wait for the next call
          *out = std::move(priority_.front());
          priority_.pop_front();
          ++popped_;
          return true;
        }
      }
      const std::size_t take = std::min<std::size_t>(s.take, items_.size() - 1);
      const std::size_t dropped = std::min(s.dropped, take);
      for (std::size_t i = 0; i < take; ++i) on_skip(items_[i], items_[take]);
      *out = std::move(items_[take]);
      items_.erase(items_.begin(), items_.begin() + static_cast<std::ptrdiff_t>(take) + 1);
      dropped_ += static_cast<long>(dropped);
      skipped_ += static_cast<long>(take - dropped);
    }
    ++popped_;
    return true;
  }

  /// pop() without the wait: false when nothing is queued (now).
  bool tryPop(T* out) {
    MutexLock lock(&mutex_);
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
      MutexLock lock(&mutex_);
      closed_ = true;
    }
    wake_.notify_all();
  }

  std::size_t capacity() const { return capacity_; }
  /// Items dropped because the queue was full.
  long dropped() const {
    MutexLock lock(&mutex_);
    return dropped_;
  }
  /// Items waiting (bounded and priority).
  std::size_t size() const {
    MutexLock lock(&mutex_);
    return items_.size() + priority_.size();
  }
  /// Bounded items accepted by push() (including those dropped later).
  long pushed() const {
    MutexLock lock(&mutex_);
    return pushed_;
  }
  /// Items popSelected() passed over for a newer one.
  long skipped() const {
    MutexLock lock(&mutex_);
    return skipped_;
  }
  /// Times popSelected() waited for a newer item at its selector's request (Selection::hold_until).
  long holds() const {
    MutexLock lock(&mutex_);
    return holds_;
  }
  /// Items handed out by pop().
  long popped() const {
    MutexLock lock(&mutex_);
    return popped_;
  }
  /// Threads blocked in pop() right now (lets a test wait until the worker is idle).
  int waiting() const {
    MutexLock lock(&mutex_);
    return waiting_;
  }
  bool closed() const {
    MutexLock lock(&mutex_);
    return closed_;
  }

 private:
  const std::size_t capacity_;
  const DropHandler on_drop_;
  mutable Mutex mutex_;
  std::condition_variable wake_;
  std::deque<T> items_ GUARDED_BY(mutex_);
  std::deque<T> priority_ GUARDED_BY(mutex_);
  bool closed_ GUARDED_BY(mutex_) = false;
  long dropped_ GUARDED_BY(mutex_) = 0;
  long pushed_ GUARDED_BY(mutex_) = 0;
  long popped_ GUARDED_BY(mutex_) = 0;
  long skipped_ GUARDED_BY(mutex_) = 0;
  long holds_ GUARDED_BY(mutex_) = 0;
  int waiting_ GUARDED_BY(mutex_) = 0;
};

/// The worker's loop: takes the items of `queue` until it is closed and drained, and calls
/// process(item, prepared) for each in order. With `threads` > 0, up to `threads` items already
/// waiting are taken out early and `prepare`d (P(const T&)) by that many long-lived threads
/// (OrderedPrefetch) while the item before them is processed; an item is never waited for:
/// one taken while none is in preparation is processed at once (prepared null). Drop policy: the
/// items taken out early are the worker's, no longer the queue's to drop.
template <typename T, typename P, typename Prepare, typename Process>
void drainWithPrepareAhead(BoundedWorkQueue<T>& queue, int threads, Prepare prepare, Process process) {
  using Item = std::pair<T, P>;
  OrderedPrefetch<Item, T> ahead(threads, [&prepare](T item, int) {
    P p = prepare(static_cast<const T&>(item));
    return Item(std::move(item), std::move(p));
  });
  const std::size_t n = static_cast<std::size_t>(threads < 0 ? 0 : threads);
  for (;;) {
    T item{};  // value-initialised: gcc 10 (bullseye) warns maybe-uninitialized for T = int otherwise
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

/// ~drop_policy newest: the capacity of the worker's queue for a `queue_size` (the frames the worker
/// waits behind while it cannot choose). Deeper, so that a stall of the worker does not make the
/// queue drop frames the choice never saw (a full queue drops the oldest, maybe the frame a
/// keyframe was due at, which can split the session); the choice skips the rest, so the depth
/// costs no latency while the choice can predict (without a prediction the frames are processed in
/// order, as without skipping: the latency grows then, up to this depth).
inline std::size_t newestCapacity(std::size_t queue_size) { return std::max<std::size_t>(1, 20 * queue_size); }

/// What the newest policy's choice returned: the item to take, and whether it was chosen with a
/// prediction (else the oldest, as processing every item: drainNewest bounds the wait).
struct NewestChoice {
  std::size_t index = 0;
  bool predicted = true;
  /// Set: wait for the next item rather than take this one, for at most this long from now (drainNewest
  /// keeps the first such deadline of each take: the waits for one item end by it).
  std::optional<std::chrono::steady_clock::duration> wait_for = std::nullopt;
};

/// The worker's loop under ~drop_policy newest, until `queue` is closed and drained. For each item:
///   - choose(const std::deque<T>& waiting, const std::vector<bool>& started) picks it (NewestChoice),
///     `started`: whether each waiting item's preparation on arrival is under way (empty without
///     `prefetch`); the items before it are skipped (on_skip(skipped, taken), counted by the queue).
///     Without a prediction at most `bound` items are kept: the older ones are dropped (counted as
///     the queue's drops, as a full queue of `bound` does; the odometry passes its queue's depth).
///   - its preparation on arrival, if a `prefetch` thread started it (by arrival(item)), is taken
///     (a superseded item's is discarded, a busy thread not waited for); otherwise prepared is null.
///     A numbering error is reported by on_error and the item processed without it.
///   - process(item, prepared, start): `start` is before the take, so a wait for the preparation
///     is part of its cost.
template <typename T, typename P, typename Choose, typename OnSkip, typename Arrival, typename Process,
          typename OnError>
void drainNewest(BoundedWorkQueue<T>& queue, std::size_t bound, OrderedPrefetch<P, T>* prefetch, Choose choose,
                 OnSkip on_skip, Arrival arrival, Process process, OnError on_error) {
  using Clock = std::chrono::steady_clock;
  std::optional<Clock::time_point> deadline;  // of the current take's waits for a newer item
  const auto select = [&](const std::deque<T>& waiting) {
    std::vector<bool> started;
    if (prefetch) {
      started.reserve(waiting.size());
      for (const T& w : waiting) started.push_back(prefetch->started(arrival(w)));
    }
    const NewestChoice c = choose(waiting, static_cast<const std::vector<bool>&>(started));
    Selection s{c.index, 0, std::nullopt};
    if (!c.predicted && waiting.size() > bound) {
      s.dropped = waiting.size() - bound;
      s.take = std::max(s.take, s.dropped);
    }
    if (c.wait_for) {
      const Clock::time_point now = Clock::now();
      if (!deadline) deadline = now + *c.wait_for;
      if (now < *deadline) s.hold_until = deadline;
    }
    return s;
  };
  T item{};
  while (deadline.reset(), queue.popSelected(&item, select, on_skip)) {
    const auto start = std::chrono::steady_clock::now();
    std::optional<P> prepared;
    try {
      if (prefetch) prepared = prefetch->takeIfStarted(arrival(item));
    } catch (const std::exception& e) {
      on_error(std::string(e.what()));
    }
    process(item, prepared ? &*prepared : static_cast<P*>(nullptr), start);
    item = T();
  }
}

}  // namespace core
}  // namespace uw_multislam
