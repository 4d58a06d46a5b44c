// BoundedWorkQueue (core/common/work_queue.h): drop policy, shutdown drain, wake-ups, thread safety.
// Threads are awaited on conditions (waiting(), futures); the timeouts are only deadlines that
// turn a hang into a failure, never the thing asserted.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <deque>
#include <functional>
#include <future>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "uw_multislam/core/common/work_queue.h"

namespace uw_multislam {
namespace core {
namespace {

constexpr auto kDeadline = std::chrono::seconds(10);

/// Waits until `q` has `n` threads blocked in pop(); false after the deadline.
template <typename T>
bool awaitWaiting(const BoundedWorkQueue<T>& q, int n) {
  const auto end = std::chrono::steady_clock::now() + kDeadline;
  while (q.waiting() != n) {
    if (std::chrono::steady_clock::now() > end) return false;
    std::this_thread::yield();
  }
  return true;
}

TEST(BoundedWorkQueue, RefusesZeroCapacity) { EXPECT_THROW(BoundedWorkQueue<int>(0), std::invalid_argument); }

TEST(BoundedWorkQueue, DropsTheOldestWhenFullAndCountsIt) {
  BoundedWorkQueue<int> q(3);
  for (int i = 1; i <= 5; ++i) EXPECT_TRUE(q.push(i));
  EXPECT_EQ(q.size(), 3u);
  EXPECT_EQ(q.dropped(), 2);
  EXPECT_EQ(q.pushed(), 5);
  int v = 0;
  ASSERT_TRUE(q.pop(&v));
  EXPECT_EQ(v, 3);  // 1 and 2 were the oldest
  q.push(6);
  ASSERT_TRUE(q.pop(&v));
  EXPECT_EQ(v, 4);
  ASSERT_TRUE(q.pop(&v));
  EXPECT_EQ(v, 5);
  ASSERT_TRUE(q.pop(&v));
  EXPECT_EQ(v, 6);
  EXPECT_EQ(q.size(), 0u);
  EXPECT_EQ(q.dropped(), 2);  // room again: nothing more dropped
  EXPECT_EQ(q.popped(), 4);
}

TEST(BoundedWorkQueue, TryPopTakesWhatIsQueuedWithoutWaiting) {
  BoundedWorkQueue<int> q(3);
  int v = -1;
  EXPECT_FALSE(q.tryPop(&v));  // empty: returns at once
  EXPECT_EQ(v, -1);
  q.push(1);
  q.pushPriority(7);
  q.push(2);
  ASSERT_TRUE(q.tryPop(&v));
  EXPECT_EQ(v, 7);  // priority items first, as pop()
  ASSERT_TRUE(q.tryPop(&v));
  EXPECT_EQ(v, 1);
  ASSERT_TRUE(q.pop(&v));
  EXPECT_EQ(v, 2);
  EXPECT_FALSE(q.tryPop(&v));
  EXPECT_EQ(q.popped(), 3);
  q.push(3);
  q.close();
  ASSERT_TRUE(q.tryPop(&v));  // what was queued is still handed out after close()
  EXPECT_EQ(v, 3);
  EXPECT_FALSE(q.tryPop(&v));
}

TEST(BoundedWorkQueue, TheDropHandlerHandsTheDroppedItemToItsSuccessor) {
  // As the odometry uses it: each frame carries the stamps of the frames dropped just before it,
  // so that the worker sees every stamp and a gap made by our own drops is not a time gap.
  struct Frame {
    double stamp = 0.0;
    std::vector<double> dropped_before;
  };
  BoundedWorkQueue<Frame> q(2, [](Frame& dropped, Frame& successor) {
    dropped.dropped_before.push_back(dropped.stamp);
    successor.dropped_before.insert(successor.dropped_before.begin(), dropped.dropped_before.begin(),
                                    dropped.dropped_before.end());
  });
  for (int i = 0; i < 6; ++i) q.push(Frame{static_cast<double>(i), {}});  // 0..3 dropped
  EXPECT_EQ(q.dropped(), 4);
  Frame f;
  ASSERT_TRUE(q.pop(&f));
  EXPECT_EQ(f.stamp, 4.0);
  EXPECT_EQ(f.dropped_before, (std::vector<double>{0, 1, 2, 3}));
  ASSERT_TRUE(q.pop(&f));
  EXPECT_EQ(f.stamp, 5.0);
  EXPECT_TRUE(f.dropped_before.empty());
  // Capacity 1: the successor is the item just pushed.
  BoundedWorkQueue<Frame> one(
      1, [](Frame& dropped, Frame& successor) { successor.dropped_before.push_back(dropped.stamp); });
  one.push(Frame{7.0, {}});
  one.push(Frame{8.0, {}});
  ASSERT_TRUE(one.pop(&f));
  EXPECT_EQ(f.stamp, 8.0);
  EXPECT_EQ(f.dropped_before, (std::vector<double>{7.0}));
}

TEST(BoundedWorkQueue, PopSelectedSkipsTheItemsBeforeTheChosenOneAndCountsThem) {
  BoundedWorkQueue<std::vector<int>> q(10);
  for (int i = 1; i <= 5; ++i) q.push({i});
  std::vector<int> v;
  std::size_t seen = 0;
  // Take the fourth: 1, 2, 3 are skipped, each handed to the taken item; 5 stays.
  ASSERT_TRUE(q.popSelected(
      &v,
      [&](const std::deque<std::vector<int>>& waiting) {
        seen = waiting.size();
        return 3;
      },
      [](std::vector<int>& skipped, std::vector<int>& taken) { taken.push_back(skipped.front()); }));
  EXPECT_EQ(seen, 5u);
  EXPECT_EQ(v, (std::vector<int>{4, 1, 2, 3}));
  EXPECT_EQ(q.skipped(), 3);
  EXPECT_EQ(q.popped(), 1);
  EXPECT_EQ(q.dropped(), 0);
  EXPECT_EQ(q.size(), 1u);
  // An index past the end takes the newest; 0 takes the oldest, as pop().
  q.push({6});
  ASSERT_TRUE(q.popSelected(
      &v, [](const auto&) { return 99; }, [](auto&, auto&) {}));
  EXPECT_EQ(v, std::vector<int>{6});
  EXPECT_EQ(q.skipped(), 4);
  q.push({7});
  q.push({8});
  ASSERT_TRUE(q.popSelected(
      &v, [](const auto&) { return 0; }, [](auto&, auto&) {}));
  EXPECT_EQ(v, std::vector<int>{7});
  EXPECT_EQ(q.skipped(), 4);
  EXPECT_EQ(q.pushed(), q.popped() + q.skipped() + q.dropped() + static_cast<long>(q.size()));
  q.close();
  ASSERT_TRUE(q.popSelected(
      &v, [](const auto&) { return 0; }, [](auto&, auto&) {}));
  EXPECT_FALSE(q.popSelected(
      &v, [](const auto&) { return 0; }, [](auto&, auto&) {}))
      << "closed and drained";
}

TEST(BoundedWorkQueue, CloseDrainsWhatIsQueuedThenReturnsFalse) {
  BoundedWorkQueue<std::unique_ptr<int>> q(4);  // move-only items
  q.push(std::make_unique<int>(1));
  q.push(std::make_unique<int>(2));
  q.close();
  EXPECT_FALSE(q.push(std::make_unique<int>(3)));  // refused after close
  EXPECT_FALSE(q.pushPriority(std::make_unique<int>(4)));
  std::unique_ptr<int> v;
  ASSERT_TRUE(q.pop(&v));
  EXPECT_EQ(*v, 1);
  ASSERT_TRUE(q.pop(&v));
  EXPECT_EQ(*v, 2);
  EXPECT_FALSE(q.pop(&v));
  EXPECT_FALSE(q.pop(&v));  // and stays closed
  EXPECT_EQ(q.dropped(), 0);
}

TEST(BoundedWorkQueue, PriorityItemsComeFirstAndAreNeverDropped) {
  BoundedWorkQueue<int> q(2);
  q.push(1);
  q.push(2);
  for (int i = 100; i < 110; ++i) q.pushPriority(i);  // beyond the capacity: none dropped
  q.push(3);                                          // drops 1 (the oldest bounded item)
  EXPECT_EQ(q.dropped(), 1);
  EXPECT_EQ(q.size(), 12u);
  int v = 0;
  for (int i = 100; i < 110; ++i) {
    ASSERT_TRUE(q.pop(&v));
    EXPECT_EQ(v, i);
  }
  ASSERT_TRUE(q.pop(&v));
  EXPECT_EQ(v, 2);
  ASSERT_TRUE(q.pop(&v));
  EXPECT_EQ(v, 3);
}

TEST(BoundedWorkQueue, ABlockedPopWakesOnPush) {
  BoundedWorkQueue<int> q(2);
  std::future<std::pair<bool, int>> popped = std::async(std::launch::async, [&q] {
    int v = -1;
    const bool ok = q.pop(&v);
    return std::make_pair(ok, v);
  });
  ASSERT_TRUE(awaitWaiting(q, 1)) << "the worker never blocked in pop()";
  q.push(42);
  ASSERT_EQ(popped.wait_for(kDeadline), std::future_status::ready) << "pop() did not wake on push()";
  const auto r = popped.get();
  EXPECT_TRUE(r.first);
  EXPECT_EQ(r.second, 42);
}

TEST(BoundedWorkQueue, BlockedPopsWakeOnClose) {
  BoundedWorkQueue<int> q(2);
  std::vector<std::future<bool>> pops;
  for (int i = 0; i < 3; ++i) {
    pops.push_back(std::async(std::launch::async, [&q] {
      int v = 0;
      return q.pop(&v);
    }));
  }
  ASSERT_TRUE(awaitWaiting(q, 3)) << "the workers never blocked in pop()";
  q.close();
  for (auto& p : pops) {
    ASSERT_EQ(p.wait_for(kDeadline), std::future_status::ready) << "pop() did not wake on close()";
    EXPECT_FALSE(p.get());
  }
}

TEST(BoundedWorkQueue, ConcurrentProducersLoseOnlyWhatIsCountedAsDropped) {
  BoundedWorkQueue<int> q(8);
  std::atomic<long> received{0};
  std::atomic<long> sum{0};
  std::thread worker([&] {
    int v = 0;
    while (q.pop(&v)) {
      ++received;
      sum += v;
    }
  });
  constexpr int kProducers = 4, kEach = 5000;
  std::vector<std::thread> producers;
  for (int p = 0; p < kProducers; ++p) {
    producers.emplace_back([&q] {
      for (int i = 0; i < kEach; ++i) q.push(1);
    });
  }
  for (auto& t : producers) t.join();
  q.close();
  worker.join();  // the worker drains what was queued at close, then pop() returns false
  EXPECT_EQ(q.pushed(), kProducers * kEach);
  EXPECT_EQ(received.load() + q.dropped(), kProducers * kEach);
  EXPECT_EQ(sum.load(), received.load());
  EXPECT_EQ(q.size(), 0u);
}

// The worker's loop with preparation ahead: every item processed once, in order; only items
// already waiting are prepared ahead, so the first of a burst is processed without waiting.
TEST(DrainWithPrepareAhead, ProcessesEveryItemInOrderAndPreparesOnlyWaitingOnes) {
  for (int threads : {0, 1, 2}) {
    BoundedWorkQueue<int> q(100);
    for (int i = 0; i < 40; ++i) q.push(i);
    q.close();
    std::vector<int> order;
    int prepared = 0;
    drainWithPrepareAhead<int, int>(
        q, threads, [](const int& item) { return item * 10; },
        [&](int& item, int* p) {
          order.push_back(item);
          if (p) {
            EXPECT_EQ(*p, item * 10) << "its own preparation";
            ++prepared;
          }
        });
    ASSERT_EQ(order.size(), 40u) << threads << " threads";
    for (int i = 0; i < 40; ++i) EXPECT_EQ(order[static_cast<std::size_t>(i)], i);
    // The first item is taken with nothing in preparation: processed as it is; then the window
    // (threads items) is refilled from the waiting ones before each, so all but the first are prepared.
    EXPECT_EQ(prepared, threads == 0 ? 0 : 39) << threads << " threads";
  }
}

TEST(DrainWithPrepareAhead, AnItemArrivingAloneIsNotHeldForPreparation) {
  BoundedWorkQueue<int> q(10);
  std::promise<void> first_processed;
  std::atomic<int> with_preparation{0};
  std::thread worker([&] {
    drainWithPrepareAhead<int, int>(
        q, 2, [](const int& item) { return item; },
        [&](int& item, int* p) {
          if (p) ++with_preparation;
          if (item == 0) first_processed.set_value();
        });
  });
  ASSERT_TRUE(awaitWaiting(q, 1));
  q.push(0);  // alone: processed at once, without a preparation thread
  ASSERT_EQ(first_processed.get_future().wait_for(kDeadline), std::future_status::ready);
  q.close();
  worker.join();
  EXPECT_EQ(with_preparation.load(), 0);
}

TEST(BoundedWorkQueue, ASelectionCountsItsOldestAsDroppedAndTheRestAsSkipped) {
  BoundedWorkQueue<int> q(10);
  for (int i = 0; i < 6; ++i) q.push(i);
  int v = -1;
  std::vector<int> passed;
  ASSERT_TRUE(q.popSelected(
      &v,
      [](const std::deque<int>&) {
        return Selection{4, 3};
      },
      [&](int& s, int&) { passed.push_back(s); }));
  EXPECT_EQ(v, 4);
  EXPECT_EQ(passed, (std::vector<int>{0, 1, 2, 3}));  // every one handed on, dropped or skipped
  EXPECT_EQ(q.dropped(), 3);
  EXPECT_EQ(q.skipped(), 1);
  EXPECT_EQ(q.size(), 1u);
}

/// drainNewest on `q` (bound 5, no preparation) with `choose`, while the worker stalls (CPU
/// starvation) in item 0 until items 1..`burst` are queued; then the queue is closed and drained.
/// Returns the items processed, in order; `on_skip` gets each skipped or dropped item.
template <typename Choose>
std::vector<int> drainAfterAStall(BoundedWorkQueue<int>& q, int burst, Choose choose,
                                  const std::function<void(int&)>& on_skip) {
  std::promise<void> stalled, release;
  std::shared_future<void> released = release.get_future().share();
  std::vector<int> processed;
  std::thread worker([&] {
    drainNewest<int, int>(
        q, 5, nullptr, choose, [&](int& s, int&) { on_skip(s); },
        [](const int& i) { return static_cast<std::size_t>(i); },
        [&](int& item, int* prepared, std::chrono::steady_clock::time_point) {
          EXPECT_EQ(prepared, nullptr);
          processed.push_back(item);
          if (item == 0) {
            stalled.set_value();
            released.wait();
          }
        },
        [](const std::string& e) { ADD_FAILURE() << e; });
  });
  q.push(0);
  // (EXPECT, not ASSERT, while the worker runs: it is released and joined either way.)
  EXPECT_EQ(stalled.get_future().wait_for(kDeadline), std::future_status::ready);
  for (int i = 1; i <= burst; ++i) q.push(i);
  release.set_value();
  q.close();
  worker.join();
  return processed;
}

// The newest policy's worker when it stalls (CPU starvation) while a burst arrives at 4x: the
// choice sees every frame of the burst, so none is lost to a full queue (one was, with the former
// queue of 5 frames, and with it the frame a keyframe was due at: a split session).
TEST(DrainNewest, ABurstDuringAStallIsChosenFromNotDropped) {
  BoundedWorkQueue<int> q(newestCapacity(5));
  std::vector<int> skipped;
  const std::vector<int> processed = drainAfterAStall(
      q, 40,
      [](const std::deque<int>& w, const std::vector<bool>& started) {
        EXPECT_TRUE(started.empty()) << "nothing prepared on arrival";
        for (std::size_t i = 0; i + 1 < w.size(); ++i)
          if (w[i] % 8 == 0) return NewestChoice{i, true};  // a keyframe due at every 8th frame
        return NewestChoice{w.size() - 1, true};            // else the newest
      },
      [&](int& s) { skipped.push_back(s); });
  EXPECT_EQ(q.dropped(), 0);
  EXPECT_EQ(processed, (std::vector<int>{0, 8, 16, 24, 32, 40})) << "every due frame, then the newest";
  EXPECT_EQ(processed.size() + skipped.size(), 41u) << "every frame processed or skipped";
  EXPECT_EQ(q.skipped(), 35);
}

// Without a prediction (tracking lost, no session yet) the oldest is taken, as processing every
// frame: then the wait is bounded as by the former queue, the older frames counted as dropped.
TEST(DrainNewest, WithoutAPredictionAtMostTheBoundWaits) {
  BoundedWorkQueue<int> q(newestCapacity(5));
  int handed_on = 0;
  const std::vector<int> processed = drainAfterAStall(
      q, 12,
      [](const std::deque<int>&, const std::vector<bool>&) {
        return NewestChoice{0, false};
      },
      [&](int&) { ++handed_on; });
  EXPECT_EQ(processed, (std::vector<int>{0, 8, 9, 10, 11, 12}));
  EXPECT_EQ(q.dropped(), 7);
  EXPECT_EQ(q.skipped(), 0);
  EXPECT_EQ(handed_on, 7) << "the dropped frames' stamps handed on";
}

// With frames prepared on arrival: the choice gets one flag per waiting frame, and an item is
// processed with its own preparation or none, never another's.
TEST(DrainNewest, AnItemGetsItsOwnPreparationOrNone) {
  struct Item {
    int value = -1;
    std::size_t arrival = 0;
  };
  core::OrderedPrefetch<int, Item> prefetch(
      1, [](Item i, int) { return i.value * 10; }, core::OrderedPrefetch<int, Item>::Start::kNewest);
  BoundedWorkQueue<Item> q(newestCapacity(5));
  for (int i = 0; i < 30; ++i) {
    Item item{i, 0};
    item.arrival = prefetch.submit(item);
    q.push(item);
  }
  q.close();
  int processed = 0, with_preparation = 0;
  drainNewest<Item, int>(
      q, 5, &prefetch,
      [](const std::deque<Item>& w, const std::vector<bool>& started) {
        EXPECT_EQ(started.size(), w.size());
        return NewestChoice{w.size() - 1, true};
      },
      [](Item&, Item&) {}, [](const Item& i) { return i.arrival; },
      [&](Item& item, int* prepared, std::chrono::steady_clock::time_point) {
        ++processed;
        if (prepared) {
          ++with_preparation;
          EXPECT_EQ(*prepared, item.value * 10);
        }
      },
      [](const std::string& e) { ADD_FAILURE() << e; });
  EXPECT_EQ(processed, 1) << "the newest of the 30 waiting";
  EXPECT_LE(with_preparation, 1);
  EXPECT_EQ(q.skipped(), 29);
}

// Selection::hold_until: the worker waits inside popSelected() for a newer item. The selectors
// below signal (a promise, under the queue's lock) when they asked for a hold, so the test acts
// during the hold without a sleep; the holds that must end by themselves are checked from below
// only (the time taken is at least the hold).
using Clock = std::chrono::steady_clock;

TEST(BoundedWorkQueue, APushDuringAHoldEndsItAndTheSelectorChoosesAgain) {
  BoundedWorkQueue<int> q(10);
  q.push(1);
  std::promise<void> held;
  std::vector<std::size_t> asked;  // the waiting items at each call (worker thread; read after join)
  std::vector<int> passed;
  int taken = -1;
  bool ok = false;
  const Clock::time_point start = Clock::now();
  Clock::time_point end;
  std::thread worker([&] {
    ok = q.popSelected(
        &taken,
        [&](const std::deque<int>& w) {
          asked.push_back(w.size());
          Selection s{w.size() - 1, 0, std::nullopt};
          if (asked.size() == 1) {
            s.hold_until = Clock::now() + kDeadline;  // a push must end it long before
            held.set_value();
          }
          return s;
        },
        [&](int& s, int&) { passed.push_back(s); });
    end = Clock::now();
  });
  ASSERT_EQ(held.get_future().wait_for(kDeadline), std::future_status::ready);
  q.push(2);
  worker.join();
  ASSERT_TRUE(ok);
  EXPECT_EQ(taken, 2) << "the newer item";
  EXPECT_EQ(asked, (std::vector<std::size_t>{1, 2})) << "chosen again with the new item";
  EXPECT_EQ(passed, (std::vector<int>{1}));
  EXPECT_EQ(q.skipped(), 1);
  EXPECT_EQ(q.holds(), 1);
  EXPECT_EQ(q.size(), 0u);
  EXPECT_LT(end - start, kDeadline / 2) << "woken by the push, not by the time";
}

TEST(BoundedWorkQueue, AHoldWithoutAPushEndsAtItsTime) {
  BoundedWorkQueue<int> q(10);
  q.push(1);
  q.push(2);
  const auto hold = std::chrono::milliseconds(100);
  int calls = 0, taken = -1;
  Clock::time_point until;
  const Clock::time_point start = Clock::now();
  ASSERT_TRUE(q.popSelected(
      &taken,
      [&](const std::deque<int>& w) {
        Selection s{w.size() - 1, 0, std::nullopt};
        if (++calls == 1) s.hold_until = until = Clock::now() + hold;  // once: the queue must do the waiting
        return s;
      },
      [](int&, int&) {}));
  const Clock::time_point end = Clock::now();
  EXPECT_GE(end - start, hold);
  EXPECT_GE(end, until);
  EXPECT_EQ(calls, 2);
  EXPECT_EQ(taken, 2);
  EXPECT_EQ(q.skipped(), 1);
  EXPECT_EQ(q.holds(), 1);
  // A hold whose time has passed already: chosen again at once, still counted as a hold.
  q.push(3);
  calls = 0;
  ASSERT_TRUE(q.popSelected(
      &taken,
      [&](const std::deque<int>&) {
        Selection s;
        if (++calls == 1) s.hold_until = Clock::now() - hold;
        return s;
      },
      [](int&, int&) {}));
  EXPECT_EQ(taken, 3);
  EXPECT_EQ(calls, 2);
  EXPECT_EQ(q.holds(), 2);
}

TEST(BoundedWorkQueue, CloseEndsAHoldAndTheQueuedItemIsStillHandedOut) {
  BoundedWorkQueue<int> q(10);
  q.push(1);
  std::promise<void> held;
  int calls = 0, taken = -1;
  bool ok = false;
  const Clock::time_point start = Clock::now();
  Clock::time_point end;
  std::thread worker([&] {
    ok = q.popSelected(
        &taken,
        [&](const std::deque<int>&) {
          if (++calls == 1) held.set_value();
          return Selection{0, 0, Clock::now() + kDeadline};  // always asks: the close must win
        },
        [](int&, int&) {});
    end = Clock::now();
  });
  ASSERT_EQ(held.get_future().wait_for(kDeadline), std::future_status::ready);
  q.close();
  worker.join();
  ASSERT_TRUE(ok);
  EXPECT_EQ(taken, 1);
  EXPECT_EQ(calls, 2);
  EXPECT_EQ(q.holds(), 1);
  EXPECT_LT(end - start, kDeadline / 2) << "ended by the close, not by the time";
  int v = -1;
  EXPECT_FALSE(q.popSelected(
      &v,
      [](const std::deque<int>&) {
        return Selection{0, 0, Clock::now() + kDeadline};
      },
      [](int&, int&) {}))
      << "closed and drained";
  // Closed before the selector asks: no hold at all.
  BoundedWorkQueue<int> closed(10);
  closed.push(7);
  closed.close();
  ASSERT_TRUE(closed.popSelected(
      &v,
      [](const std::deque<int>&) {
        return Selection{0, 0, Clock::now() + kDeadline};
      },
      [](int&, int&) {}));
  EXPECT_EQ(v, 7);
  EXPECT_EQ(closed.holds(), 0);
}

TEST(BoundedWorkQueue, APriorityItemDuringAHoldIsServedFirstAndTheHeldItemStaysQueued) {
  BoundedWorkQueue<int> q(10);
  q.push(1);
  std::promise<void> held;
  int calls = 0, taken = -1;
  bool ok = false;
  std::thread worker([&] {
    ok = q.popSelected(
        &taken,
        [&](const std::deque<int>&) {
          if (++calls == 1) held.set_value();
          return Selection{0, 0, Clock::now() + kDeadline};
        },
        [](int&, int&) { ADD_FAILURE() << "nothing is skipped"; });
  });
  ASSERT_EQ(held.get_future().wait_for(kDeadline), std::future_status::ready);
  q.pushPriority(99);
  worker.join();
  ASSERT_TRUE(ok);
  EXPECT_EQ(taken, 99);
  EXPECT_EQ(calls, 1) << "not chosen again: the bounded items wait for the next call";
  EXPECT_EQ(q.size(), 1u);
  EXPECT_EQ(q.popped(), 1);
  EXPECT_EQ(q.skipped(), 0);
  int v = -1;
  ASSERT_TRUE(q.popSelected(
      &v, [](const std::deque<int>&) { return std::size_t{0}; }, [](int&, int&) {}));
  EXPECT_EQ(v, 1);
}

// drainNewest keeps the first deadline of a take: the chooser's later asks (after each new item)
// do not move it. The first ask waits 300 ms, the one after the push 10 s: the take must come by
// the first deadline (so well before 10 s), and no sooner. The next take has its own deadline.
TEST(DrainNewest, AWaitForTheNextItemEndsByTheTakesFirstDeadline) {
  BoundedWorkQueue<int> q(newestCapacity(5));
  const auto first_wait = std::chrono::milliseconds(300);
  std::promise<void> asked;
  std::mutex m;
  std::vector<Clock::time_point> asks;     // guarded by m
  std::vector<std::size_t> waiting_sizes;  // guarded by m
  std::vector<std::pair<int, Clock::time_point>> processed;
  std::vector<int> skipped;
  std::thread worker([&] {
    drainNewest<int, int>(
        q, 5, nullptr,
        [&](const std::deque<int>& w, const std::vector<bool>&) {
          std::lock_guard<std::mutex> lock(m);
          asks.push_back(Clock::now());
          waiting_sizes.push_back(w.size());
          NewestChoice c{w.size() - 1, true};
          // Take 1: asks for 300 ms, then (after item 2 arrived) for 10 s. Take 2 (item 3): 300 ms again.
          c.wait_for = (w.back() == 2) ? std::chrono::duration_cast<Clock::duration>(kDeadline)
                                       : std::chrono::duration_cast<Clock::duration>(first_wait);
          if (asks.size() == 1) asked.set_value();
          return c;
        },
        [&](int& s, int&) { skipped.push_back(s); }, [](const int& i) { return static_cast<std::size_t>(i); },
        [&](int& item, int*, Clock::time_point) { processed.emplace_back(item, Clock::now()); },
        [](const std::string& e) { ADD_FAILURE() << e; });
  });
  q.push(1);
  ASSERT_EQ(asked.get_future().wait_for(kDeadline), std::future_status::ready);
  q.push(2);  // during the first ask's hold: chosen again, asks for 10 s
  // The take of 2, then a lone item 3 with its own (new) deadline.
  // (EXPECT, not ASSERT, while the worker runs: the close below ends any hold, so it is joined.)
  const auto end = Clock::now() + kDeadline;
  while (q.popped() < 1 && Clock::now() < end) std::this_thread::yield();
  EXPECT_EQ(q.popped(), 1) << "take 1 not by its first deadline";
  q.push(3);
  while (q.popped() < 2 && Clock::now() < end) std::this_thread::yield();
  q.close();
  worker.join();
  ASSERT_EQ(processed.size(), 2u);
  EXPECT_EQ(processed[0].first, 2);
  EXPECT_EQ(processed[1].first, 3);
  EXPECT_EQ(skipped, (std::vector<int>{1}));
  std::lock_guard<std::mutex> lock(m);
  ASSERT_GE(asks.size(), 4u);
  // Take 1: no sooner than the first ask's deadline, and not after the second ask's 10 s.
  EXPECT_GE(processed[0].second - asks[0], first_wait);
  EXPECT_LT(processed[0].second - asks[0], kDeadline / 2) << "the second ask moved the deadline";
  // Take 2's deadline is its own (from its first ask), not take 1's, which had passed.
  const auto take2_first_ask =
      std::find_if(asks.begin(), asks.end(), [&](const Clock::time_point& t) { return t > processed[0].second; });
  ASSERT_NE(take2_first_ask, asks.end());
  EXPECT_GE(processed[1].second - *take2_first_ask, first_wait) << "take 2 held for its own wait";
  EXPECT_EQ(q.holds(), 3) << "take 1: two holds (before and after item 2); take 2: one";
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
