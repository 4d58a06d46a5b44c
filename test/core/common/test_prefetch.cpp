// Frames prepared ahead on worker threads (OrderedPrefetch + FramePreparer, what offline_slam
// --threads N and the odometry nodelet's ~prepare_threads run) give exactly the odometry of
// frames prepared in line.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <cmath>
#include <memory>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include "../../common/rendered_seabed.h"
#include "uw_multislam/core/common/ordered_prefetch.h"
#include "uw_multislam/core/frontend/odometry.h"
#include "uw_multislam/core/frontend/tracking.h"

namespace uw_multislam {
namespace core {
namespace {

TEST(OrderedPrefetch, HandsOutEveryItemInOrderWithinTheLookahead) {
  for (int threads : {0, 1, 2, 4}) {
    const std::size_t n = 200, ahead = 3;
    std::atomic<std::size_t> consumed{0};
    std::atomic<long> worst{-1000};  // max over items of (item - consumed) when it was started
    OrderedPrefetch<std::string> p(n, threads, ahead, [&](std::size_t item, int worker) {
      EXPECT_GE(worker, 0);
      EXPECT_LT(worker, std::max(threads, 1));
      const long lead = static_cast<long>(item) - static_cast<long>(consumed.load());
      long w = worst.load();
      while (lead > w && !worst.compare_exchange_weak(w, lead)) {
      }
      return "item " + std::to_string(item);
    });
    for (std::size_t i = 0; i < n; ++i) {
      ASSERT_FALSE(p.done());
      EXPECT_EQ(p.next(), "item " + std::to_string(i)) << threads << " threads";
      consumed = i + 1;
    }
    EXPECT_TRUE(p.done());
    EXPECT_THROW(p.next(), std::out_of_range);
    // An item is started only once the one `ahead` before it was handed out (consumed is
    // updated just after next() returns, hence the + 1).
    EXPECT_LE(worst.load(), static_cast<long>(ahead)) << threads << " threads";
  }
}

TEST(OrderedPrefetch, AnErrorComesOutAtItsItemAndTheRestFollow) {
  for (int threads : {0, 2}) {
    OrderedPrefetch<int> p(6, threads, 2, [](std::size_t item, int) {
      if (item == 3) throw std::runtime_error("bad item 3");
      return static_cast<int>(item) * 10;
    });
    for (int i = 0; i < 3; ++i) EXPECT_EQ(p.next(), i * 10);
    try {
      p.next();
      ADD_FAILURE() << "item 3 should throw";
    } catch (const std::runtime_error& e) {
      EXPECT_STREQ(e.what(), "bad item 3");
    }
    EXPECT_EQ(p.next(), 40);
    EXPECT_EQ(p.next(), 50);
  }
}

TEST(OrderedPrefetch, StopsWithItemsNeverHandedOut) {
  std::atomic<int> started{0};
  {
    OrderedPrefetch<int> p(1000, 2, 4, [&](std::size_t item, int) {
      ++started;
      return static_cast<int>(item);
    });
    EXPECT_EQ(p.next(), 0);
  }  // the destructor returns: the workers were stopped, not left waiting
  EXPECT_LE(started.load(), 1 + 4 + 2);  // the window, plus items taken as it moved
}

// The odometry nodelet's use: items submitted as they come (only those already waiting), handed
// out in the order submitted, each computed once, with per-worker state.
TEST(OrderedPrefetch, HandsOutSubmittedItemsInTheOrderSubmitted) {
  for (int threads : {0, 1, 3}) {
    std::vector<std::atomic<int>> computed(100);
    OrderedPrefetch<std::string, std::string> p(threads, [&](std::string item, int worker) {
      EXPECT_GE(worker, 0);
      EXPECT_LT(worker, std::max(threads, 1));
      ++computed[static_cast<std::size_t>(std::stoi(item.substr(5)))];
      return item + " done";
    });
    EXPECT_TRUE(p.done());
    EXPECT_THROW(p.next(), std::out_of_range);
    int handed = 0;
    for (int burst = 1; burst <= 13; ++burst) {  // bursts of 1..13 items, handed out partly in between
      for (int k = 0; k < burst && handed + static_cast<int>(p.pending()) < 91; ++k)
        p.submit("item " + std::to_string(handed + static_cast<int>(p.pending())));
      for (int k = 0; k < burst / 2 && !p.done(); ++k, ++handed)
        EXPECT_EQ(p.next(), "item " + std::to_string(handed) + " done") << threads << " threads";
    }
    while (!p.done()) EXPECT_EQ(p.next(), "item " + std::to_string(handed++) + " done");
    EXPECT_EQ(handed, 91);
    for (int i = 0; i < 91; ++i) EXPECT_EQ(computed[static_cast<std::size_t>(i)].load(), 1) << i;
  }
}

TEST(OrderedPrefetch, ASubmittedItemIsComputedBeforeItIsAskedFor) {
  std::mutex m;
  std::condition_variable cv;
  bool started = false;
  OrderedPrefetch<int, int> p(1, [&](int item, int) {
    {
      std::lock_guard<std::mutex> lock(m);
      started = true;
    }
    cv.notify_all();
    return item * 2;
  });
  p.submit(21);
  std::unique_lock<std::mutex> lock(m);
  EXPECT_TRUE(cv.wait_for(lock, std::chrono::seconds(10), [&] { return started; })) << "no worker took it";
  lock.unlock();
  EXPECT_EQ(p.next(), 42);
}

// Start::kNewest, the odometry nodelet's ~prepare_threads with drop_policy newest: every frame is
// submitted as it arrives; a worker starts only the newest one; the consumer takes one frame by
// its number and gets that frame's own result or nothing (then it prepares the frame itself).
// The work below waits at a gate the test opens, so which item a worker has started is known.
class NewestFirst : public ::testing::Test {
 protected:
  using Prefetch = OrderedPrefetch<std::string, int>;
  Prefetch* make(int threads) {
    prefetch_ = std::make_unique<Prefetch>(
        threads,
        [this](int item, int) {
          std::unique_lock<std::mutex> lock(m_);
          started_.push_back(item);
          changed_.notify_all();
          changed_.wait(lock, [&] { return all_open_ || open_.count(item) > 0; });
          ++computed_;
          return "prepared " + std::to_string(item);
        },
        Prefetch::Start::kNewest);
    return prefetch_.get();
  }
  void TearDown() override {  // after a failed assertion too: no worker left at a closed gate
    {
      std::lock_guard<std::mutex> lock(m_);
      all_open_ = true;
      changed_.notify_all();
    }
    prefetch_.reset();
  }
  void open(int item) {
    std::lock_guard<std::mutex> lock(m_);
    open_.insert(item);
    changed_.notify_all();
  }
  /// Waits until a worker has started `item` (false after 10 s: a failure, not a timing).
  bool awaitStarted(int item) {
    std::unique_lock<std::mutex> lock(m_);
    return changed_.wait_for(lock, std::chrono::seconds(10),
                             [&] { return std::find(started_.begin(), started_.end(), item) != started_.end(); });
  }
  std::vector<int> started() {
    std::lock_guard<std::mutex> lock(m_);
    return started_;
  }

  std::mutex m_;
  std::condition_variable changed_;
  std::vector<int> started_;  // items a worker started, in order (under m_)
  std::set<int> open_;        // items whose work may finish (under m_)
  bool all_open_ = false;     // (under m_)
  int computed_ = 0;          // (under m_)
  std::unique_ptr<Prefetch> prefetch_;
};

TEST_F(NewestFirst, AWorkerStartsTheNewestAndTheTakenItemGetsItsOwnResult) {
  Prefetch* p = make(1);
  EXPECT_EQ(p->submit(0), 0u);
  ASSERT_TRUE(awaitStarted(0));
  // While the worker is busy with 0, items 1 and 2 arrive: 2 supersedes 1, which is never started.
  EXPECT_EQ(p->submit(1), 1u);
  EXPECT_EQ(p->submit(2), 2u);
  open(0);
  ASSERT_TRUE(awaitStarted(2));
  EXPECT_EQ(started(), (std::vector<int>{0, 2}));
  EXPECT_EQ(p->pending(), 3u);
  EXPECT_TRUE(p->started(0));   // done
  EXPECT_FALSE(p->started(1));  // superseded
  EXPECT_TRUE(p->started(2));   // under way
  EXPECT_FALSE(p->started(3));  // not submitted
  open(2);
  // The consumer took item 2 (0 and 1 skipped): 2's own result, not 0's (computed, superseded).
  const std::optional<std::string> got = p->takeIfStarted(2);
  ASSERT_TRUE(got.has_value());
  EXPECT_EQ(*got, "prepared 2");
  EXPECT_EQ(p->discardedComputed(), 1);  // item 0: computed, then discarded
  EXPECT_TRUE(p->done());
  EXPECT_FALSE(p->started(2));                           // handed out
  EXPECT_THROW(p->takeIfStarted(1), std::out_of_range);  // handed out (discarded) already
  EXPECT_THROW(p->takeIfStarted(3), std::out_of_range);  // not submitted
  EXPECT_THROW(p->next(), std::logic_error);             // kNewest hands out by number only
  std::lock_guard<std::mutex> lock(m_);
  EXPECT_EQ(computed_, 2);  // 1 never computed
}

TEST_F(NewestFirst, AnItemNoWorkerStartedIsTheCallersAndADiscardedOneIsNotReused) {
  Prefetch* p = make(1);
  p->submit(0);
  ASSERT_TRUE(awaitStarted(0));
  p->submit(1);
  // The only worker is busy with 0: 1 was not started, so the consumer is told to compute it itself
  // (not given 0's result, not made to wait for 0), and 1 is never started later.
  EXPECT_FALSE(p->takeIfStarted(1).has_value());
  EXPECT_TRUE(p->done());
  // Item 0 was in progress when item 1 was taken: its result is thrown away when done.
  open(0);
  p->submit(2);
  ASSERT_TRUE(awaitStarted(2));  // after 0 finished (one worker)
  EXPECT_EQ(p->discardedComputed(), 1);
  open(2);
  EXPECT_EQ(p->takeIfStarted(2).value_or("none"), "prepared 2");
  EXPECT_EQ(started(), (std::vector<int>{0, 2}));
}

TEST_F(NewestFirst, AnOlderItemTakenAfterANewerArrivedIsComputedByTheCaller) {
  // The skip rule may take an older frame (the keyframe due) and leave newer ones waiting: the
  // older one, superseded, is the caller's; the newer one keeps its own result for later.
  Prefetch* p = make(2);
  p->submit(0);
  ASSERT_TRUE(awaitStarted(0));
  p->submit(1);
  ASSERT_TRUE(awaitStarted(1));  // the second worker was free
  p->submit(2);
  p->submit(3);  // supersedes 2: both workers are busy
  EXPECT_FALSE(p->takeIfStarted(2).has_value());  // 0 and 1 discarded (in progress), 2 superseded
  open(0);
  open(1);
  ASSERT_TRUE(awaitStarted(3));
  open(3);
  EXPECT_EQ(p->takeIfStarted(3).value_or("none"), "prepared 3");
  EXPECT_EQ(started(), (std::vector<int>{0, 1, 3}));
}

TEST(OrderedPrefetch, NewestWithoutWorkersLeavesEveryItemToTheCaller) {
  int computed = 0;
  OrderedPrefetch<int, int> p(
      0, [&](int item, int) { return ++computed, item; }, OrderedPrefetch<int, int>::Start::kNewest);
  for (int i = 0; i < 3; ++i) p.submit(i);
  EXPECT_FALSE(p.takeIfStarted(0).has_value());
  EXPECT_FALSE(p.takeIfStarted(2).has_value());
  EXPECT_EQ(computed, 0);
  EXPECT_TRUE(p.done());
}

TEST(OrderedPrefetch, TakeIfStartedRethrowsTheWorkersError) {
  std::mutex m;
  std::condition_variable cv;
  bool started = false;
  OrderedPrefetch<int, int> p(
      1,
      [&](int item, int) -> int {
        {
          std::lock_guard<std::mutex> lock(m);
          started = true;
        }
        cv.notify_all();
        throw std::runtime_error("bad item " + std::to_string(item));
      },
      OrderedPrefetch<int, int>::Start::kNewest);
  p.submit(7);
  {
    std::unique_lock<std::mutex> lock(m);
    ASSERT_TRUE(cv.wait_for(lock, std::chrono::seconds(10), [&] { return started; })) << "no worker took it";
  }
  try {
    p.takeIfStarted(0);
    ADD_FAILURE() << "item 0 should throw";
  } catch (const std::runtime_error& e) {
    EXPECT_STREQ(e.what(), "bad item 7");
  }
}

// The odometry of a stream whose frames were prepared by workers equals the odometry that
// prepares them itself: the same statuses, keyframes, features, inliers and poses to the bit,
// through tracking loss (blank frames), an unsupported encoding and a wrong image size.
class PreparedFrames : public testing_util::RenderedSeabedTest {
 protected:
  std::vector<OdometryInput> mission() const {
    std::vector<OdometryInput> frames;
    for (int k = 0; k < 40; ++k) {
      OdometryInput in;
      in.index = k;
      in.stamp_s = 0.5 * k;
      in.altitude_m = 2.0 + 0.01 * (k % 5);
      const double x = 1.8 + 0.12 * (k < 20 ? k : k + 30);  // a jump after the blank frames
      in.image = render(Pose2(x, 3.0 + 0.3 * std::sin(0.2 * k), 0.1 * std::sin(0.15 * k)), in.altitude_m);
      if (k >= 14 && k < 21) in.image = cv::Mat(240, 320, CV_8UC3, cv::Scalar(80, 80, 80));  // tracking lost
      if (k == 5) in.image = cv::Mat(240, 320, CV_16UC1, cv::Scalar(1000));  // unsupported: skipped
      if (k == 8) in.image = cv::Mat(120, 160, CV_8UC3, cv::Scalar(80, 80, 80));  // wrong size: skipped
      frames.push_back(in);
    }
    return frames;
  }

  void compare(const OdometryOptions& options) {
    const TrackingLossOptions loss;
    const std::vector<OdometryInput> frames = mission();
    // A lens with distortion, so that the preparer's undistortion of the keypoints counts too.
    CameraIntrinsics lens = camera_;
    lens.distortion_model = DistortionModel::kPlumbBob;
    lens.distortion = {-0.05, 0.01, 0.0, 0.0, 0.0};
    SegmentedOdometry inline_odo(lens, options, loss), prepared_odo(lens, options, loss);
    std::vector<std::unique_ptr<FramePreparer>> preparers;
    for (int w = 0; w < 2; ++w) preparers.push_back(std::make_unique<FramePreparer>(lens, options));
    OrderedPrefetch<PreparedFrame> ahead(frames.size(), 2, 4, [&](std::size_t i, int worker) {
      return preparers[worker]->prepare(frames[i].image);
    });
    int errors = 0, sessions_started = 0;
    for (const OdometryInput& in : frames) {
      PreparedFrame p = ahead.next();
      if (!p.error.empty()) ++errors;
      const SegmentedOdometry::Step a = inline_odo.process(in);
      const SegmentedOdometry::Step b = prepared_odo.process(in, &p);
      const OdometryUpdate &u = a.update, &v = b.update;
      SCOPED_TRACE("frame " + std::to_string(in.index) + " (" + statusName(u.status) + ": " + u.reason + ")");
      EXPECT_EQ(u.status, v.status);
      EXPECT_EQ(u.reason, v.reason);
      EXPECT_EQ(u.keyframe_id, v.keyframe_id);
      EXPECT_EQ(u.features, v.features);
      EXPECT_EQ(u.klt, v.klt);
      EXPECT_EQ(u.matches, v.matches);
      EXPECT_EQ(u.inliers, v.inliers);
      EXPECT_EQ(u.pose.x(), v.pose.x());
      EXPECT_EQ(u.pose.y(), v.pose.y());
      EXPECT_EQ(u.pose.yaw(), v.pose.yaw());
      EXPECT_EQ(a.session_started, b.session_started);
      EXPECT_EQ(a.session_closed, b.session_closed);
      sessions_started += a.session_started;
      ASSERT_EQ(inline_odo.newKeyframes().size(), prepared_odo.newKeyframes().size());
      for (std::size_t k = 0; k < inline_odo.newKeyframes().size(); ++k) {
        const FrameFeatures &f = inline_odo.newKeyframes()[k].features, &g = prepared_odo.newKeyframes()[k].features;
        ASSERT_EQ(f.size(), g.size());
        EXPECT_EQ(cv::norm(f.descriptors, g.descriptors, cv::NORM_INF), 0.0);
        for (std::size_t j = 0; j < f.size(); ++j) EXPECT_EQ(f.keypoints[j].pt, g.keypoints[j].pt);
      }
    }
    EXPECT_EQ(errors, 1);  // the 16UC1 frame: the preparer kept the error, process skipped it
    EXPECT_EQ(sessions_started, 2);  // the blank frames closed the first session
    EXPECT_EQ(inline_odo.losses(), 1);
    // The workers' extraction is counted where the odometry's own would be.
    EXPECT_EQ(inline_odo.times().get("features").calls, prepared_odo.times().get("features").calls);
    EXPECT_EQ(inline_odo.times().get("enhance").calls, prepared_odo.times().get("enhance").calls);
  }
};

TEST_F(PreparedFrames, GiveTheSameOdometryWithSiftOnEveryFrame) {
  OdometryOptions o;
  o.klt.enabled = false;
  compare(o);
}

TEST_F(PreparedFrames, GiveTheSameOdometryWithKltBetweenKeyframes) {
  OdometryOptions o;
  o.klt.enabled = true;  // the workers only enhance: whether a frame is extracted depends on its tracks
  compare(o);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
