// Clang's thread-safety annotations (https://clang.llvm.org/docs/ThreadSafetyAnalysis.html) and a
// mutex they apply to, as abseil and cartographer have them: which mutex guards a field, which a
// function needs held or must not hold, in which order two mutexes are taken. Clang checks them
// with -Wthread-safety (-Wthread-safety-beta for the order; the CI step scripts/thread_safety_check.py);
// other compilers see nothing (the macros are empty).
//
// libstdc++'s std::mutex carries no annotation, so the analysis cannot see it locked: shared state
// is guarded by core::Mutex, held by a MutexLock for a scope (UniqueMutexLock where it is let go
// within the scope); a condition variable waits with Mutex::wait.
#pragma once

#include <chrono>
#include <condition_variable>
#include <mutex>

#if defined(__clang__)
#define UWMS_THREAD_ANNOTATION(x) __attribute__((x))
#else
#define UWMS_THREAD_ANNOTATION(x)
#endif

#define CAPABILITY(x) UWMS_THREAD_ANNOTATION(capability(x))
#define SCOPED_CAPABILITY UWMS_THREAD_ANNOTATION(scoped_lockable)
#define GUARDED_BY(x) UWMS_THREAD_ANNOTATION(guarded_by(x))
#define PT_GUARDED_BY(x) UWMS_THREAD_ANNOTATION(pt_guarded_by(x))
#define ACQUIRED_BEFORE(...) UWMS_THREAD_ANNOTATION(acquired_before(__VA_ARGS__))
#define ACQUIRED_AFTER(...) UWMS_THREAD_ANNOTATION(acquired_after(__VA_ARGS__))
#define REQUIRES(...) UWMS_THREAD_ANNOTATION(requires_capability(__VA_ARGS__))
#define REQUIRES_SHARED(...) UWMS_THREAD_ANNOTATION(requires_shared_capability(__VA_ARGS__))
#define ACQUIRE(...) UWMS_THREAD_ANNOTATION(acquire_capability(__VA_ARGS__))
#define RELEASE(...) UWMS_THREAD_ANNOTATION(release_capability(__VA_ARGS__))
#define TRY_ACQUIRE(...) UWMS_THREAD_ANNOTATION(try_acquire_capability(__VA_ARGS__))
#define EXCLUDES(...) UWMS_THREAD_ANNOTATION(locks_excluded(__VA_ARGS__))
#define ASSERT_CAPABILITY(x) UWMS_THREAD_ANNOTATION(assert_capability(x))
#define RETURN_CAPABILITY(x) UWMS_THREAD_ANNOTATION(lock_returned(x))
#define NO_THREAD_SAFETY_ANALYSIS UWMS_THREAD_ANNOTATION(no_thread_safety_analysis)

namespace uw_multislam {
namespace core {

/// std::mutex as a capability the analysis knows. Lockable (lock, unlock, try_lock), so that
/// std::scoped_lock and std::unique_lock work with it too (unseen by the analysis).
class CAPABILITY("mutex") Mutex {
 public:
  Mutex() = default;
  Mutex(const Mutex&) = delete;
  Mutex& operator=(const Mutex&) = delete;

  void lock() ACQUIRE() { mutex_.lock(); }
  void unlock() RELEASE() { mutex_.unlock(); }
  bool try_lock() TRY_ACQUIRE(true) { return mutex_.try_lock(); }
  /// Tells the analysis that the calling thread holds it (a lambda run under it: a condition's
  /// predicate, a callback the holder calls).
  void assertHeld() const ASSERT_CAPABILITY(this) {}

  /// Waits on `cv` until pred() (called with the mutex held), releasing the mutex meanwhile.
  template <typename Predicate>
  void wait(std::condition_variable& cv, Predicate pred) REQUIRES(this) {
    adopted([&](std::unique_lock<std::mutex>& lock) { cv.wait(lock, pred); });
  }
  /// wait() for `timeout` at most; pred()'s value at the end.
  template <typename Rep, typename Period, typename Predicate>
  bool waitFor(std::condition_variable& cv, const std::chrono::duration<Rep, Period>& timeout, Predicate pred)
      REQUIRES(this) {
    return adopted([&](std::unique_lock<std::mutex>& lock) { return cv.wait_for(lock, timeout, pred); });
  }
  /// wait() until `deadline` at the latest; pred()'s value at the end.
  template <typename Clock, typename Duration, typename Predicate>
  bool waitUntil(std::condition_variable& cv, const std::chrono::time_point<Clock, Duration>& deadline, Predicate pred)
      REQUIRES(this) {
    return adopted([&](std::unique_lock<std::mutex>& lock) { return cv.wait_until(lock, deadline, pred); });
  }

 private:
  // f(lock), `lock` owning the mutex the caller holds; held again when f returns or throws, and
  // still the caller's to release.
  template <typename F>
  auto adopted(F f) {
    std::unique_lock<std::mutex> lock(mutex_, std::adopt_lock);
    struct Keep {
      std::unique_lock<std::mutex>& lock;
      ~Keep() { lock.release(); }
    } keep{lock};
    return f(lock);
  }

  std::mutex mutex_;
};

/// Holds a Mutex for its scope.
class SCOPED_CAPABILITY MutexLock {
 public:
  explicit MutexLock(Mutex* mutex) ACQUIRE(mutex) : mutex_(mutex) { mutex_->lock(); }
  ~MutexLock() RELEASE() { mutex_->unlock(); }
  MutexLock(const MutexLock&) = delete;
  MutexLock& operator=(const MutexLock&) = delete;

 private:
  Mutex* const mutex_;
};

/// Holds a Mutex for its scope, and lets it go and take it again within it (unlock(), lock()).
class SCOPED_CAPABILITY UniqueMutexLock {
 public:
  explicit UniqueMutexLock(Mutex* mutex) ACQUIRE(mutex) : mutex_(mutex) { mutex_->lock(); }
  ~UniqueMutexLock() RELEASE() {
    if (held_) mutex_->unlock();
  }
  UniqueMutexLock(const UniqueMutexLock&) = delete;
  UniqueMutexLock& operator=(const UniqueMutexLock&) = delete;

  void unlock() RELEASE() {
    mutex_->unlock();
    held_ = false;
  }
  void lock() ACQUIRE() {
    mutex_->lock();
    held_ = true;
  }

 private:
  Mutex* const mutex_;
  bool held_ = true;
};

}  // namespace core
}  // namespace uw_multislam
