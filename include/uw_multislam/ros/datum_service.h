// The back-end's datum (doc/frames.md, doc/ros_api.md "set_datum"): which one is in use at
// start-up, and set_datum, which sets or moves it at sea as robot_localization's navsat_transform
// does. The datum is map's origin on WGS84 and the compass heading of the first keyframe's x axis
// (z up); `map` is published ENU there (core::MapFrame); FramePublisher publishes earth -> map,
// map -> utm and keyframe_fix from it; the session store keeps the one
// set_datum gave (SessionManager::storeDatum), so a restart keeps a datum set at sea.
//
// The rules (the least surprising, written out in doc/ros_api.md):
//  - at start-up the store's datum, when it holds one, wins over ~datum/* (the launch file does
//    not know what was set at sea); a ~datum/* that differs is named in a WARN;
//  - set_datum with no datum in use sets it; with the same one it changes nothing (OK); with
//    another one it answers ALREADY_EXISTS naming the datum in use, and moves it only with
//    `replace` (moving earth -> map moves every published position on the earth: a script that
//    calls set_datum at each surfacing must not do that unasked; navsat_transform always replaces).
// Threading: the service runs on the node's callback thread; it takes its own mutex (one
// set_datum at a time), then the worker's lock for the store write only.
#pragma once

#include <ros/node_handle.h>
#include <ros/service_server.h>

#include <functional>
#include <mutex>
#include <optional>
#include <string>

#include "uw_multislam/SetDatum.h"
#include "uw_multislam/core/common/status.h"
#include "uw_multislam/core/export/survey_export.h"
#include "uw_multislam/core/session/session_worker.h"
#include "uw_multislam/ros/frame_publisher.h"

namespace uw_multislam {
namespace ros_geo {

/// set_datum's request as a datum: heading_deg with with_heading, else the first keyframe's x axis east.
core::GeoOrigin datumFromRequest(const uw_multislam::SetDatum::Request& r);

/// Whether set_datum may put `wanted` in place of `current` (from `current_source`): OK (the
/// message "unchanged" when it is the same datum), INVALID_ARGUMENT (core::checkDatum, or a polar
/// datum with a UTM frame), ALREADY_EXISTS (another datum in use and not `replace`). Nothing else
/// is checked here (the store write is the caller's).
core::Status checkSetDatum(const std::optional<core::GeoOrigin>& current, const std::string& current_source,
                           const core::GeoOrigin& wanted, bool replace, const std::string& utm_frame);

/// The datum in use at start-up: the store's text (parsed) over the parameters'. `source` says
/// whose; `notes` what the log must say (a store's datum over different parameters, a damaged
/// text). Throws std::invalid_argument for a damaged stored text (the store is not used blindly).
std::optional<core::GeoOrigin> startDatum(const std::optional<core::GeoOrigin>& params,
                                          const std::optional<std::string>& stored, std::string* source,
                                          std::vector<std::string>* notes);

class DatumService {
 public:
  using Say = std::function<void(const std::string&)>;
  /// Decides the datum in use (startDatum, the store read under the worker's lock), hands it to
  /// `frames` and advertises set_datum on `nh`. `worker` and `frames` must outlive this. Throws
  /// StoreError (the store unreadable) and std::invalid_argument (a damaged stored datum, a polar
  /// one with a UTM frame).
  DatumService(ros::NodeHandle nh, core::SessionWorker* worker, ros_frames::FramePublisher* frames,
               const ros_frames::FrameOptions& options, Say say);
  /// What set_datum calls, under the worker's lock, once it has moved the datum: the back-end
  /// publishes its sessions again (paths, poses, markers in the new `map` axes). Thread-safe.
  void republishWith(std::function<void(const core::SessionQueries&)> republish);

 private:
  bool onSetDatum(uw_multislam::SetDatum::Request& req, uw_multislam::SetDatum::Response& res);

  core::SessionWorker* worker_;
  ros_frames::FramePublisher* frames_;
  const std::string utm_frame_;
  const Say say_;
  std::mutex mutex_;    // one set_datum at a time; guards source_ and republish_
  std::string source_;  // of the datum in use: "~datum/* parameters", "set_datum"
  std::function<void(const core::SessionQueries&)> republish_;
  ros::ServiceServer server_;
};

}  // namespace ros_geo
}  // namespace uw_multislam
