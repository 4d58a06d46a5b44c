// The back-end's client of other vehicles' keyframe_features services (hash exchange between
// vehicles): a loop detector asks our back-end for the features of another vehicle's keyframe
// when it is a loop candidate, and this client forwards the request to that vehicle
// (~fleet/peers: vehicle -> service) and puts the answer back into our ids.
//
// Bounded: each call runs on a thread of its own and is waited for at most ~fleet/peer_timeout_s
// (core::BoundedCalls); a call left at the deadline is answered UNAVAILABLE, counted, and that
// vehicle is not asked again for as long (back-off: a vehicle out of reach costs the loop
// detector one wait, not one per candidate). Each vehicle's service client is persistent and made
// again after a failure. Thread-safe: calls for several vehicles (or the same) may run side by
// side; its mutex is never held during a call.
#pragma once

#include <ros/node_handle.h>
#include <ros/service_client.h>

#include <chrono>
#include <map>
#include <mutex>
#include <string>

#include "uw_multislam/KeyframeFeatures.h"
#include "uw_multislam/core/common/bounded_call.h"

namespace uw_multislam {
namespace ros_fleet {

struct PeerStats {
  long requested = 0;       // requests forwarded (or refused before: no service, backing off)
  long bytes_received = 0;  // serialised answers' size
  long failures = 0;        // not answered OK
  long timeouts = 0;        // left at the deadline
};

class PeerClient {
 public:
  /// `peers`: each other vehicle's keyframe_features service; `timeout_s` > 0.
  PeerClient(const ros::NodeHandle& nh, std::map<std::string, std::string> peers, double timeout_s);

  /// Keyframe `request.keyframe` of `vehicle`'s session `remote_session`, asked of that vehicle;
  /// the answer in our ids (`local_session`, frame `frame_id`). FAILED_PRECONDITION when
  /// ~fleet/peers names no service for it, UNAVAILABLE when it does not answer in time (or is
  /// being left alone after that), else that vehicle's own answer.
  uw_multislam::KeyframeFeatures::Response request(const std::string& vehicle, int remote_session, int local_session,
                                                   const uw_multislam::KeyframeFeatures::Request& request,
                                                   const std::string& frame_id);
  PeerStats stats() const;

 private:
  ros::NodeHandle nh_;
  const std::map<std::string, std::string> peers_;
  const double timeout_s_;
  core::BoundedCalls calls_;  // thread-safe on its own
  mutable std::mutex mutex_;  // guards the three below
  std::map<std::string, ros::ServiceClient> clients_;
  std::map<std::string, std::chrono::steady_clock::time_point> quiet_until_;  // not asked before this
  PeerStats stats_;
};

}  // namespace ros_fleet
}  // namespace uw_multislam
