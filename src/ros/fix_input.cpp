#include "uw_multislam/ros/fix_input.h"

#include <optional>
#include <vector>

namespace uw_multislam {
namespace ros_geo {

core::NavFix fromMsg(const sensor_msgs::NavSatFix& msg) {
  core::NavFix f;
  f.stamp_s = msg.header.stamp.toSec();
  f.status = msg.status.status;
  f.lat_deg = msg.latitude;
  f.lon_deg = msg.longitude;
  f.covariance_type = msg.position_covariance_type;
  for (int k = 0; k < 9; ++k) f.covariance[k] = msg.position_covariance[k];
  return f;
}

FixInput::FixInput(ros::NodeHandle nh, const std::string& topic, const core::FixOptions& options,
                   const std::string& base_frame, core::SessionWorker* worker, ros_frames::FramePublisher* frames)
    : base_frame_(base_frame), worker_(worker), frames_(frames), matcher_(options) {
  sub_ = nh.subscribe(topic, 100, &FixInput::onFix, this);
  timer_ = nh.createSteadyTimer(ros::WallDuration(0.2), [this](const ros::SteadyTimerEvent&) {
    bool waiting = false;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      waiting = matcher_.waiting() > 0;
    }
    if (waiting) matchWaiting();
  });
}

std::unique_ptr<FixInput> FixInput::make(ros::NodeHandle nh, const ros_params::BackendNodeletOptions& options,
                                         core::SessionWorker* worker, ros_frames::FramePublisher* frames) {
  if (options.fix_topic.empty()) return nullptr;
  return std::make_unique<FixInput>(nh, options.fix_topic, options.fix, options.frames.base_frame, worker, frames);
}

long FixInput::refusals() const {
  long n = 0;
  for (int r = 0; r < static_cast<int>(core::FixRefusal::kCount); ++r)
    n += matcher_.refused(static_cast<core::FixRefusal>(r));
  return n;
}

void FixInput::warnIfRefused(long before) {
  if (refusals() > before) ROS_WARN_THROTTLE(5, "back-end: %s", matcher_.lastRefusal().c_str());
}

void FixInput::onFix(const sensor_msgs::NavSatFixConstPtr& msg) {
  const bool have_datum = frames_->datum().has_value();
  core::NavFix fix = fromMsg(*msg);
  const std::string& frame = msg->header.frame_id;
  std::string why;
  const std::optional<Eigen::Vector2d> arm =
      frame.empty() || frame == base_frame_ ? std::optional<Eigen::Vector2d>() : frames_->inBasePlane(frame, &why);
  if (arm) fix.antenna = *arm;
  fix.antenna_known = why.empty();
  if (!why.empty()) ROS_WARN_THROTTLE(10, "back-end: fixes in frame '%s' refused: %s", frame.c_str(), why.c_str());
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (arm && (frame != said_frame_ || *arm != said_arm_)) {
      said_frame_ = frame, said_arm_ = *arm;
      ROS_INFO("back-end: fixes in frame '%s': its lever arm from %s is (%.3f, %.3f) m", frame.c_str(),
               base_frame_.c_str(), arm->x(), arm->y());
    }
    const long before = refusals();
    matcher_.add(fix, have_datum);
    warnIfRefused(before);
  }
  matchWaiting();
}

void FixInput::matchWaiting() {
  const std::optional<core::GeoOrigin> datum = frames_->datum();
  const core::CameraMount mount = frames_->mount();
  const int given = worker_->locked([&](core::SessionManager& m) {
    const core::SessionQueries& q = m.view();
    std::lock_guard<std::mutex> lock(mutex_);
    if (matcher_.waiting() == 0) return 0;
    // The datum places `map`, which is the active session's map (doc/frames.md); while the session
    // is relocalised in a stored map, `map` is drawn in that map's frame instead: no map takes fixes.
    const int active = q.activeSession();
    const bool own = active >= 0 && q.has(active) && q.hasKeyframe(active) && !q.relocalise(active);
    const int datum_map = own ? q.mapOf(active) : -1;
    const long before = refusals();
    const std::vector<core::FixPrior> priors = matcher_.match(q, datum, datum_map, mount);
    const int n = matcher_.give(&m, priors);
    warnIfRefused(before);
    return n;
  });
  if (given > 0) worker_->optimiseDue();  // the maps the priors made due
}

void FixInput::counters(ros_diagnostics::BackendCounters* c) const {
  using R = core::FixRefusal;
  std::lock_guard<std::mutex> lock(mutex_);
  c->fixes_used = matcher_.used(), c->fixes_waiting = static_cast<long>(matcher_.waiting());
  c->fixes_refused_no_fix = matcher_.refused(R::kNoFix), c->fixes_refused_not_finite = matcher_.refused(R::kNotFinite);
  c->fixes_refused_unknown_covariance = matcher_.refused(R::kUnknownCovariance);
  c->fixes_refused_bad_variance = matcher_.refused(R::kBadVariance);
  c->fixes_refused_no_datum = matcher_.refused(R::kNoDatum);
  c->fixes_refused_no_keyframe = matcher_.refused(R::kNoKeyframe);
  c->fixes_refused_other_map = matcher_.refused(R::kOtherMap);
  c->fixes_refused_map_origin = matcher_.refused(R::kMapOrigin);
  c->fixes_refused_keyframe_has_fix = matcher_.refused(R::kKeyframeHasFix);
  c->fixes_refused_outlier = matcher_.refused(R::kOutlier);
  c->fixes_refused_no_lever_arm = matcher_.refused(R::kNoLeverArm);
}

}  // namespace ros_geo
}  // namespace uw_multislam
