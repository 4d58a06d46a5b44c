#include "uw_multislam/ros/fleet_peer_client.h"

#include <ros/serialization.h>

#include <cstdio>
#include <memory>
#include <utility>

#include "uw_multislam/ros/backend_conversions.h"

namespace uw_multislam {
namespace ros_fleet {

namespace rc = ros_conversions;

PeerClient::PeerClient(const ros::NodeHandle& nh, std::map<std::string, std::string> peers, double timeout_s)
    : nh_(nh), peers_(std::move(peers)), timeout_s_(timeout_s) {}

PeerStats PeerClient::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

uw_multislam::KeyframeFeatures::Response PeerClient::request(const std::string& vehicle, int remote_session,
                                                             int local_session,
                                                             const uw_multislam::KeyframeFeatures::Request& req,
                                                             const std::string& frame_id) {
  uw_multislam::KeyframeFeatures::Response res;
  const auto peer = peers_.find(vehicle);
  if (peer == peers_.end()) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ++stats_.requested;
      ++stats_.failures;
    }
    res.status = rc::toStatusMsg(
        {core::StatusCode::kFailedPrecondition, "session " + std::to_string(local_session) + " is vehicle " + vehicle +
                                                    "'s, and ~fleet/peers names no keyframe_features service for it"});
    return res;
  }
  const std::string who = "vehicle " + vehicle + "'s " + peer->second;
  char limit[64];
  std::snprintf(limit, sizeof limit, "%.1f s (~fleet/peer_timeout_s)", timeout_s_);
  const auto now = std::chrono::steady_clock::now();
  std::unique_lock<std::mutex> lock(mutex_);
  if (const auto quiet = quiet_until_.find(vehicle); quiet != quiet_until_.end() && now < quiet->second) {
    ++stats_.requested;
    ++stats_.failures;
    res.status = rc::toStatusMsg({core::StatusCode::kUnavailable, who + " did not answer its last request within " +
                                                                      limit + ": not asked again for as long"});
    return res;
  }
  uw_multislam::KeyframeFeatures there;
  there.request = req;
  there.request.session = remote_session;
  ros::ServiceClient& client = clients_[vehicle];
  if (!client.isValid()) client = nh_.serviceClient<uw_multislam::KeyframeFeatures>(peer->second, true);
  ros::ServiceClient call = client;  // a copy: the call itself runs without the lock
  lock.unlock();
  // BoundedCalls runs it on a thread of its own, which owns copies of what it touches.
  auto exchange = std::make_shared<uw_multislam::KeyframeFeatures>(there);
  auto answered = std::make_shared<bool>(false);
  std::string error;
  const core::BoundedCalls::Outcome outcome = calls_.call(
      vehicle, [call, exchange, answered]() mutable { *answered = call.call(*exchange); }, timeout_s_, &error);
  lock.lock();
  ++stats_.requested;
  if (outcome != core::BoundedCalls::Outcome::kDone || !*answered) {
    ++stats_.failures;
    std::string why = who + " did not answer";
    if (outcome == core::BoundedCalls::Outcome::kTimedOut) {
      ++stats_.timeouts;
      why += std::string(" within ") + limit;
      quiet_until_[vehicle] =
          std::chrono::steady_clock::now() +
          std::chrono::duration_cast<std::chrono::steady_clock::duration>(std::chrono::duration<double>(timeout_s_));
      // Our persistent link to it dropped: roscpp then fails the hung call (its thread and the
      // key are freed; BoundedCalls refuses the key until then); the next request makes a new one.
      call.shutdown();
      clients_[vehicle] = ros::ServiceClient();
    } else {
      if (outcome == core::BoundedCalls::Outcome::kBusy) why = who + " has not returned an earlier request yet";
      if (outcome == core::BoundedCalls::Outcome::kThrew) why += ": " + error;
      clients_[vehicle].shutdown();  // made again at the next request
    }
    res.status = rc::toStatusMsg({core::StatusCode::kUnavailable, why});
    return res;
  }
  res = exchange->response;
  if (res.status.code != uw_multislam::Status::OK) ++stats_.failures;
  stats_.bytes_received += static_cast<long>(ros::serialization::serializationLength(res));
  res.keyframe.session = local_session;  // in our ids
  res.keyframe.header.frame_id = frame_id;
  return res;
}

}  // namespace ros_fleet
}  // namespace uw_multislam
