#include "uw_multislam/ros/fleet_hash_exchange.h"

#include <ros/console.h>
#include <ros/serialization.h>

#include <utility>

#include "uw_multislam/Keyframe.h"
#include "uw_multislam/ros/backend_conversions.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace ros_fleet {

namespace rc = ros_conversions;

HashExchange::HashExchange(ros::NodeHandle& nh, std::string vehicle, int queue_size, bool hash_codes,
                           std::string session_frame_prefix, core::SessionWorker* worker,
                           std::function<void(const core::SessionQueries&)> opened)
    : vehicle_(std::move(vehicle)),
      hash_codes_(hash_codes),
      session_frame_prefix_(std::move(session_frame_prefix)),
      worker_(worker),
      opened_(std::move(opened)) {
  out_pub_ = nh.advertise<uw_multislam::KeyframeHash>(topics::kFleetHashesOut, queue_size);
  foreign_pub_ = nh.advertise<uw_multislam::Keyframe>(topics::kForeignKeyframes, queue_size);
}

void HashExchange::listen(ros::NodeHandle& nh, int queue_size, const std::map<std::string, std::string>& peers) {
  // Through the worker with our keyframes and loops: a loop on another vehicle's keyframe finds it.
  in_sub_ = nh.subscribe(topics::kFleetHashesIn, queue_size, &HashExchange::onHash, this);
  std::string names;
  for (const auto& [name, service] : peers) names += " " + name + " (" + service + ")";
  ROS_INFO("back-end: hash exchange as vehicle %s: our keyframes on %s, theirs from %s; features of%s",
           vehicle_.c_str(), nh.resolveName(topics::kFleetHashesOut).c_str(),
           nh.resolveName(topics::kFleetHashesIn).c_str(), names.empty() ? " nobody (no ~fleet/peers)" : names.c_str());
}

void HashExchange::hashIfMissing(rc::KeyframeData* k) const {
  if (k->hash.size() != core::HalocProjections::kHashSize && !k->features.descriptors.empty())
    k->hash = worker_->hasher().hash(k->features.descriptors);
}

void HashExchange::sendOurs(const core::SessionQueries& m, rc::KeyframeData k, const std_msgs::Header& header) {
  if (k.hash.size() != core::HalocProjections::kHashSize) return;  // nothing to compare (no features)
  const core::SessionManagerOptions& o = m.options();
  const auto out = boost::make_shared<uw_multislam::KeyframeHash>(rc::toFleetHashMsg(
      std::move(k), vehicle_, o.hash_mode, o.projection_seed, o.num_features, o.features, header, hash_codes_));
  ++stats_.hashes_sent;
  stats_.hash_bytes_sent += static_cast<long>(ros::serialization::serializationLength(*out));
  out_pub_.publish(out);
}

void HashExchange::sessionEnded(int session) {
  out_pub_.publish(
      boost::make_shared<uw_multislam::KeyframeHash>(rc::fleetSessionEndedMsg(vehicle_, session, ros::Time::now())));
}

void HashExchange::refused(const std::string& vehicle, int session, int keyframe, const std::string& why) {
  ++stats_.refused;
  ROS_WARN_THROTTLE(5, "back-end: vehicle %s's keyframe %d of session %d refused: %s", vehicle.c_str(), keyframe,
                    session, why.c_str());
}

void HashExchange::onHash(const uw_multislam::KeyframeHashConstPtr& msg) {
  ++messages_;
  if (msg->vehicle == vehicle_) return;  // ours, come back through a relay
  const std::string vehicle = msg->vehicle;
  if (msg->session_ended) {
    worker_->endForeignSession(vehicle, msg->session, msg->header.stamp.toSec(),
                               [this, vehicle](const core::SessionQueries&, const core::Status& st) {
                                 if (st.ok()) {
                                   ++stats_.sessions_ended;
                                   return;
                                 }
                                 ROS_WARN_THROTTLE(5, "back-end: vehicle %s's session-ended notice: %s",
                                                   vehicle.c_str(), st.message.c_str());
                               });
    return;
  }
  rc::KeyframeData k;
  rc::KeyframeHashData h;
  std::string why;
  if (!rc::fromFleetHashMsg(*msg, &k, &h, &why)) {
    worker_->locked([&](const core::SessionQueries&) { refused(vehicle, msg->session, msg->keyframe, why); });
    return;
  }
  const long bytes = static_cast<long>(ros::serialization::serializationLength(*msg));
  worker_->addForeignKeyframe(
      vehicle, {h.mode, h.projection_seed, h.num_features, "", h.features},
      rc::toKeyframeInput(k, msg->header.stamp.toSec()),
      [this, vehicle, k, header = msg->header, bytes](const core::SessionQueries& m, const core::KeyframeInput& in,
                                                      const core::Status& st, int local, bool opened) mutable {
        if (!st.ok()) return refused(vehicle, in.session, in.keyframe, st.message);
        if (opened && opened_) opened_(m);  // it took an id: our next session takes another
        ++stats_.hashes_received;
        stats_.hash_bytes_received += bytes;
        k.session = local;  // in our ids, for the loop detector(s)
        header.frame_id = session_frame_prefix_ + std::to_string(local);
        foreign_pub_.publish(boost::make_shared<uw_multislam::Keyframe>(rc::toKeyframeMsg(k, header)));
      });
}

}  // namespace ros_fleet
}  // namespace uw_multislam
