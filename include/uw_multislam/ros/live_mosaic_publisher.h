// The back-end's live mosaic (core/export/live_mosaic.h) on the `mosaic` topic (latched): the
// active map, the active keyframe outlined, redrawn at most at ~mosaic_rate when it changed
// (markDue: keyframes, joins, splits, optimisations) and someone subscribes.
//
// Threading: a thread of its own. At most every 1 / rate seconds it copies the active map's poses
// out under the worker's lock (core::liveMosaicSnapshot: poses only, the images are shared), then
// warps, draws and publishes WITHOUT it. The keyframes' images have a mutex of their own, taken
// after the worker's (add() is called from the worker's callbacks). The destructor stops the
// thread: destroy this before the worker.
#pragma once

#include <ros/node_handle.h>
#include <ros/publisher.h>

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "uw_multislam/core/export/live_mosaic.h"
#include "uw_multislam/core/session/session_worker.h"

namespace uw_multislam {
namespace ros_mosaic {

struct MosaicStats {
  long published = 0;
  int drawn = 0, missing = 0;  // keyframes of the last drawing
  double ms = 0.0, resolution_m = 0.0;
  double images_kB = 0.0;  // the keyframes' images kept
};

class LiveMosaicPublisher {
 public:
  /// rate_hz <= 0: off (advertised, never drawn, no image kept). `map_frame`: the published map's
  /// axes at each drawing (core::turnLiveMosaic: north up with a datum); empty: the core's.
  LiveMosaicPublisher(ros::NodeHandle& nh, const core::SessionWorker& worker, double rate_hz,
                      const core::LiveMosaicOptions& options, std::string frame_id,
                      std::function<core::MapFrame()> map_frame = {});
  ~LiveMosaicPublisher();
  LiveMosaicPublisher(const LiveMosaicPublisher&) = delete;
  LiveMosaicPublisher& operator=(const LiveMosaicPublisher&) = delete;

  bool on() const { return rate_hz_ > 0; }
  /// A keyframe's image (its JPEG thumbnail); ignored when off.
  void add(int session, int keyframe, double altitude_m, const core::CameraIntrinsics& camera,
           std::vector<std::uint8_t> jpeg);
  /// A reloaded session's images (their thumbnails); the mosaic drawn again.
  void add(const core::ReloadedSession& session);
  /// Forgets a session's images (unload, delete).
  void removeSession(int session);
  /// The active map may look different: drawn again at the next turn.
  void markDue() { due_ = true; }
  MosaicStats stats() const;

 private:
  void run();

  const core::SessionWorker& worker_;
  std::function<core::MapFrame()> map_frame_;
  const double rate_hz_;
  const core::LiveMosaicOptions options_;
  const std::string frame_id_;
  ros::Publisher pub_;
  mutable std::mutex mutex_;       // guards images_ and stats_ (taken after the worker's lock)
  core::LiveMosaicImages images_;  // each keyframe's image, at the mosaic's resolution
  MosaicStats stats_;
  std::mutex wait_mutex_;  // guards stop_ (with wake_)
  std::condition_variable wake_;
  bool stop_ = false;
  std::atomic<bool> due_{true};  // the active map changed since the last drawing
  std::thread thread_;
};

}  // namespace ros_mosaic
}  // namespace uw_multislam
