#include "uw_multislam/ros/datum_service.h"

#include <stdexcept>
#include <utility>

#include "uw_multislam/core/export/geo_datum.h"
#include "uw_multislam/ros/backend_conversions.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace ros_geo {

using core::Status;
using core::StatusCode;

namespace {
const char kFromParams[] = "~datum/* parameters";
const char kFromService[] = "set_datum";
}  // namespace

core::GeoOrigin datumFromRequest(const uw_multislam::SetDatum::Request& r) {
  core::GeoOrigin d;
  d.lat_deg = r.latitude_deg;
  d.lon_deg = r.longitude_deg;
  d.alt_m = r.altitude_m;
  d.heading_deg = r.with_heading ? r.heading_deg : core::kEnuHeadingDeg;
  return d;
}

Status checkSetDatum(const std::optional<core::GeoOrigin>& current, const std::string& current_source,
                     const core::GeoOrigin& wanted, bool replace, const std::string& utm_frame) {
  if (const std::string bad = core::checkDatum(wanted); !bad.empty())
    return {StatusCode::kInvalidArgument, "set_datum: " + bad + ": nothing changed"};
  if (!utm_frame.empty()) {
    try {
      core::utmFromMap(wanted);
    } catch (const std::invalid_argument& e) {
      return {StatusCode::kInvalidArgument,
              std::string("set_datum: ") + e.what() + ", and ~datum/utm_frame is '" + utm_frame + "': nothing changed"};
    }
  }
  if (current && core::sameDatum(*current, wanted))
    return Status::Ok("unchanged: the datum in use is already " + core::describeDatum(wanted));
  if (current && !replace)
    return {StatusCode::kAlreadyExists, "set_datum: the datum in use is " + core::describeDatum(*current) + " (from " +
                                            current_source + "); call again with replace: true to move map to " +
                                            core::describeDatum(wanted) + ": nothing changed"};
  return Status::Ok();
}

std::optional<core::GeoOrigin> startDatum(const std::optional<core::GeoOrigin>& params,
                                          const std::optional<std::string>& stored, std::string* source,
                                          std::vector<std::string>* notes) {
  *source = kFromParams;
  if (!stored) return params;
  core::GeoOrigin d;
  std::string why;
  if (!core::parseDatumText(*stored, &d, &why))
    throw std::invalid_argument("the session store's " + why +
                                ": damaged (set ~store_path to another file, or repair its meta row 'datum')");
  *source = std::string(kFromService) + " in an earlier run (kept in the session store)";
  if (params && !core::sameDatum(*params, d))
    notes->push_back("datum: the session store's " + core::describeDatum(d) + " (set with set_datum) is used, not " +
                     kFromParams + "' " + core::describeDatum(*params) +
                     "; call set_datum with replace: true to move it");
  return d;
}

DatumService::DatumService(ros::NodeHandle nh, core::SessionWorker* worker, ros_frames::FramePublisher* frames,
                           const ros_frames::FrameOptions& options, Say say)
    : worker_(worker), frames_(frames), utm_frame_(options.utm_frame), say_(std::move(say)) {
  const std::optional<std::string> stored =
      worker_->locked([](const core::SessionQueries& m) { return m.storedDatum(); });
  std::vector<std::string> notes;
  const std::optional<core::GeoOrigin> d = startDatum(options.datum, stored, &source_, &notes);
  for (const std::string& line : d ? frames_->setDatum(*d) : frames_->noDatum()) say_(line);
  if (d) say_("datum: from " + source_);
  for (const std::string& line : notes) ROS_WARN("back-end: %s", line.c_str());
  server_ = nh.advertiseService(topics::kSetDatumService, &DatumService::onSetDatum, this);
}

void DatumService::republishWith(std::function<void(const core::SessionQueries&)> republish) {
  std::lock_guard<std::mutex> lock(mutex_);
  republish_ = std::move(republish);
}

bool DatumService::onSetDatum(uw_multislam::SetDatum::Request& req, uw_multislam::SetDatum::Response& res) {
  const core::GeoOrigin wanted = datumFromRequest(req);
  std::lock_guard<std::mutex> lock(mutex_);
  const std::optional<core::GeoOrigin> current = frames_->datum();
  Status st = checkSetDatum(current, source_, wanted, req.replace, utm_frame_);
  if (st.ok() && st.message.empty()) {
    const Status kept = worker_->locked([&](core::SessionManager& m) { return m.storeDatum(core::datumText(wanted)); });
    if (kept.code == StatusCode::kDataLoss) {
      st = {StatusCode::kDataLoss, "set_datum: " + kept.message + ": nothing changed"};
    } else {
      for (const std::string& line : frames_->setDatum(wanted)) say_(line);
      if (republish_) worker_->locked([this](const core::SessionQueries& m) { republish_(m); });
      st.message = "datum " + core::describeDatum(wanted) +
                   (current ? " in place of " + core::describeDatum(*current) + " (from " + source_ + ")" : "") +
                   ": map (ENU there), earth -> map, map -> utm and keyframe_fix follow it; " +
                   (kept.ok() ? "kept in the session store (a restart keeps it)"
                              : "NOT kept across a restart (" + kept.message + ")");
      source_ = kFromService;
      say_("set_datum: " + st.message);
    }
  }
  if (!st.ok()) ROS_WARN("back-end: %s", st.message.c_str());
  res.status = ros_conversions::toStatusMsg(st);  // an OK status carries no message: the words go to `note`
  if (st.ok()) res.note = st.message;
  const std::optional<core::GeoOrigin> now = frames_->datum();
  res.datum = now ? core::describeDatum(*now) : std::string();
  return true;
}

}  // namespace ros_geo
}  // namespace uw_multislam
