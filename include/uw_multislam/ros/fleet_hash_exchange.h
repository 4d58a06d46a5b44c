// This vehicle's side of the hash exchange between vehicles (~fleet/vehicle set): each of our
// keyframes goes out on fleet/hashes_out as a KeyframeHash (hash, motion, pose, camera; no
// features, no image), and a notice when one of our sessions ends. Another vehicle's, from
// fleet/hashes_in, is converted here and handed to the session worker, which checks its hash
// settings (core::HashSettings::compatible) and grows that vehicle's session beside ours; once
// taken it goes to the loop detector(s) on foreign_keyframes, in our ids. The features of such a
// keyframe are asked of that vehicle only when it is a loop candidate (fleet_peer_client.h).
//
// Threading: sendOurs, sessionEnded and the worker's callbacks run under the worker's lock, which
// guards the stats; onHash runs on the subscriber's thread and takes it only through the worker.
#pragma once

#include <ros/node_handle.h>
#include <ros/publisher.h>
#include <ros/subscriber.h>
#include <std_msgs/Header.h>

#include <atomic>
#include <functional>
#include <map>
#include <string>

#include "uw_multislam/KeyframeHash.h"
#include "uw_multislam/core/session/session_worker.h"
#include "uw_multislam/ros/pipeline_conversions.h"

namespace uw_multislam {
namespace ros_fleet {

struct HashExchangeStats {
  long hashes_sent = 0, hash_bytes_sent = 0;          // ours, on fleet/hashes_out
  long hashes_received = 0, hash_bytes_received = 0;  // theirs taken (foreign keyframes)
  long refused = 0, sessions_ended = 0;               // theirs refused (settings, ids), their notices taken
};

class HashExchange {
 public:
  /// Advertises fleet/hashes_out and foreign_keyframes. `opened` (under the worker's lock):
  /// another vehicle's session took one of our ids.
  HashExchange(ros::NodeHandle& nh, std::string vehicle, int queue_size, bool hash_codes,
               std::string session_frame_prefix, core::SessionWorker* worker,
               std::function<void(const core::SessionQueries&)> opened);
  /// Subscribes to fleet/hashes_in (queue_size deep: the worker's bound) and says so, naming
  /// `peers` (whose features keyframe_features asks for).
  void listen(ros::NodeHandle& nh, int queue_size, const std::map<std::string, std::string>& peers);
  void stopListening() { in_sub_.shutdown(); }
  const std::string& vehicle() const { return vehicle_; }
  /// A keyframe without a hash (an older sender) gets one, made as the manager would: the link
  /// needs it.
  void hashIfMissing(ros_conversions::KeyframeData* k) const;
  /// Our keyframe, taken by the manager (its features are not needed): out on fleet/hashes_out.
  void sendOurs(const core::SessionQueries& m, ros_conversions::KeyframeData k, const std_msgs::Header& header);
  /// Our session ended: the other vehicles may join it now.
  void sessionEnded(int session);
  /// A message of fleet/hashes_in: another vehicle's keyframe or session-ended notice.
  void onHash(const uw_multislam::KeyframeHashConstPtr& msg);
  const HashExchangeStats& stats() const { return stats_; }  // under the worker's lock
  long messages() const { return messages_; }                // fleet/hashes_in messages received

 private:
  void refused(const std::string& vehicle, int session, int keyframe, const std::string& why);

  const std::string vehicle_;
  const bool hash_codes_;
  const std::string session_frame_prefix_;
  core::SessionWorker* worker_;
  const std::function<void(const core::SessionQueries&)> opened_;
  ros::Publisher out_pub_, foreign_pub_;
  ros::Subscriber in_sub_;
  std::atomic<long> messages_{0};
  HashExchangeStats stats_;  // guarded by the worker's lock
};

}  // namespace ros_fleet
}  // namespace uw_multislam
