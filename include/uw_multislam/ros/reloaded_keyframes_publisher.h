// reloaded_keyframes: the stored sessions' keyframes for the loop detector(s), so that new
// keyframes find global loops against them. A new subscriber (a loop detector, also a respawned
// one) gets every session handed over so far (core::SessionWorker::handOver: session by session,
// each under the worker's lock; hashes only when paging, else with their features read from the
// store); reload_session adds one; unload_session and delete_session publish a notice (keyframe
// -1) after which the loop detectors forget that session, in order with its keyframes.
//
// Threading: the connection callback runs on the multi-threaded queue (a large store is handed
// over while keyframes and services go on); reload() takes the worker's lock itself; forget() is
// called under it.
#pragma once

#include <ros/node_handle.h>
#include <ros/publisher.h>

#include <string>

#include "uw_multislam/core/session/session_worker.h"

namespace uw_multislam {
namespace ros_sessions {

class ReloadedKeyframesPublisher {
 public:
  /// `mt`: the multi-threaded node handle; `worker` must outlive this.
  ReloadedKeyframesPublisher(ros::NodeHandle& mt, core::SessionWorker* worker, std::string session_frame_prefix);
  /// reload_session: SessionWorker::reloadSession, its keyframes published (under the lock).
  core::Status reload(const std::string& name_or_id, core::ReloadedSession* out);
  /// The loop detectors forget the session; later subscribers do not get it (worker's lock held).
  void forget(int session);

 private:
  std::string frameOf(int session) const { return prefix_ + std::to_string(session); }

  core::SessionWorker* worker_;
  const std::string prefix_;
  ros::Publisher pub_;
};

}  // namespace ros_sessions
}  // namespace uw_multislam
