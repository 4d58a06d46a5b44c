// The bounded work queue every nodelet uses between its callbacks and its worker thread: push()
// never blocks (when full the OLDEST item is dropped and counted), pop() blocks until an item or
// close(). After close(), pop() still hands out what is queued, then returns false: a clean
// shutdown processes everything that arrived. ROS-free, header-only.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <deque>
#include <mutex>

namespace uw_multislam {
namespace ros_util {

template <typename T>
class BoundedWorkQueue {
 public:
  explicit BoundedWorkQueue(std::size_t capacity) : capacity_(capacity < 1 ? 1 : capacity) {}

  /// Adds an item; when full the oldest is dropped (counted). After close(): ignored, false.
  bool push(T item) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (closed_) return false;
      if (queue_.size() >= capacity_) {
        queue_.pop_front();
        ++dropped_;
      }
      queue_.push_back(std::move(item));
    }
    wake_.notify_one();
    return true;
  }
  /// Waits for an item; false once closed and empty.
  bool pop(T* out) {
    std::unique_lock<std::mutex> lock(mutex_);
    wake_.wait(lock, [this] { return closed_ || !queue_.empty(); });
    if (queue_.empty()) return false;
    *out = std::move(queue_.front());
    queue_.pop_front();
    return true;
  }
  void close() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      closed_ = true;
    }
    wake_.notify_all();
  }
  long dropped() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return dropped_;
  }
  std::size_t size() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return queue_.size();
  }

 private:
  const std::size_t capacity_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<T> queue_;
  bool closed_ = false;
  long dropped_ = 0;
};

}  // namespace ros_util
}  // namespace uw_multislam
