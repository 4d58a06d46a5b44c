#include "uw_multislam/core/common/bounded_call.h"

#include <chrono>
#include <exception>
#include <stdexcept>
#include <thread>

namespace uw_multislam {
namespace core {

BoundedCalls::Outcome BoundedCalls::call(const std::string& key, std::function<void()> fn, double timeout_s,
                                         std::string* error) {
  if (!(timeout_s > 0.0)) throw std::invalid_argument("BoundedCalls: the timeout must be positive");
  {
    MutexLock lock(&mutex_);
    auto it = hung_.find(key);
    if (it != hung_.end()) {
      MutexLock slot_lock(&it->second->mutex);
      if (!it->second->done) return Outcome::kBusy;
    }
    if (it != hung_.end()) hung_.erase(it);  // it has returned: the key is free again
  }
  auto slot = std::make_shared<Slot>();
  // The thread owns its copies (slot, fn): nothing of this object or of the caller. A thread that
  // cannot be started throws here, before anything is held.
  std::thread([slot, fn = std::move(fn)] {
    std::string what;
    bool threw = false;
    try {
      fn();
    } catch (const std::exception& e) {
      threw = true;
      what = e.what();
    } catch (...) {
      threw = true;
      what = "unknown exception";
    }
    {
      MutexLock lock(&slot->mutex);
      slot->done = true;
      slot->threw = threw;
      slot->error = what;
    }
    slot->done_cv.notify_all();
  }).detach();
  {
    MutexLock lock(&slot->mutex);
    if (slot->mutex.waitFor(slot->done_cv, std::chrono::duration<double>(timeout_s), [&] {
          slot->mutex.assertHeld();  // the predicate runs under the lock
          return slot->done;
        })) {
      if (!slot->threw) return Outcome::kDone;
      if (error) *error = slot->error;
      return Outcome::kThrew;
    }
  }
  MutexLock lock(&mutex_);
  hung_[key] = slot;  // the key is held until this call returns
  return Outcome::kTimedOut;
}

int BoundedCalls::running() const {
  MutexLock lock(&mutex_);
  int n = 0;
  for (const auto& [key, slot] : hung_) {
    MutexLock slot_lock(&slot->mutex);
    n += !slot->done;
  }
  return n;
}

}  // namespace core
}  // namespace uw_multislam
