// Calls that may never return (another vehicle's service over a link that has gone quiet), run
// on a thread of their own and waited for at most a deadline, so that the caller (the back-end's
// keyframe_features, and behind it the loop detector's worker) is never stalled longer. roscpp
// cannot cancel a service call, so a call that outlives its deadline keeps its thread until it
// returns; while it does, further calls under the same key are refused at once (kBusy): hung
// calls hold at most one thread per key. Calls within their deadline may run side by side under
// one key. Hand-written: std::async's future blocks in its destructor until the call returns,
// which is exactly the stall this avoids.
#pragma once

#include <condition_variable>
#include <functional>
#include <map>
#include <memory>
#include <string>

#include "uw_multislam/core/common/thread_annotations.h"

namespace uw_multislam {
namespace core {

class BoundedCalls {
 public:
  enum class Outcome {
    kDone,      // fn returned within the deadline
    kThrew,     // fn threw within the deadline (what() in *error)
    kTimedOut,  // still running at the deadline: it goes on alone, its key stays busy until it returns
    kBusy,      // an earlier call under this key timed out and has not returned: fn was not started
  };

  /// Runs fn on a new thread and waits at most timeout_s (> 0) for it. fn must own everything it
  /// touches (capture by value or shared_ptr): after kTimedOut it runs on after this returns, and
  /// after this object is gone.
  Outcome call(const std::string& key, std::function<void()> fn, double timeout_s, std::string* error = nullptr);

  /// Keys held by a call that timed out and has not returned yet.
  int running() const;

 private:
  struct Slot {
    Mutex mutex;  // taken after BoundedCalls::mutex_ when both are held
    std::condition_variable done_cv;
    bool done GUARDED_BY(mutex) = false;
    std::string error GUARDED_BY(mutex);  // fn's exception, if any
    bool threw GUARDED_BY(mutex) = false;
  };
  mutable Mutex mutex_;
  // A call of each key that timed out, until it returns.
  std::map<std::string, std::shared_ptr<Slot>> hung_ GUARDED_BY(mutex_);
};

}  // namespace core
}  // namespace uw_multislam
