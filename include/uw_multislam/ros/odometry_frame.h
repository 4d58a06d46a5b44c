// The odometry nodelet's unit of work: an image paired with its camera_info and altitude, as it waits
// in the worker's queue, and the same frame prepared ahead on another thread (~prepare_threads).
#pragma once

#include <sensor_msgs/CameraInfo.h>

#include <algorithm>
#include <cstddef>
#include <string>
#include <vector>

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/input_pairing.h"
#include "uw_multislam/core/frontend/odometry.h"
#include "uw_multislam/ros/image_input.h"

namespace uw_multislam {
namespace ros_inputs {

struct OdometryFrame {
  ImageMsg msg;
  sensor_msgs::CameraInfoConstPtr info;
  core::PairedAltitude altitude = core::PairedAltitude::kFixed;
  double altitude_m = 0.0;          // kReading: the altimeter's range, else the camera's (NaN: the last valid one)
  std::string altimeter_frame;      // of the altitude readings (empty: none yet, or no altitude topic)
  std::vector<double> passed_over;  // stamps received before it and not processed: seen, no time gap
  std::size_t arrival = 0;          // its number among the frames prepared on arrival (~prepare_threads, newest)
};

/// A frame the queue dropped when full: its stamps travel on with the frame after it, which the worker passes
/// over first, so the queue's own drops never look like a gap in the images (a new session).
inline void handOnDropped(OdometryFrame& dropped, OdometryFrame& next) {
  dropped.passed_over.push_back(dropped.msg.header().stamp.toSec());
  next.passed_over.insert(next.passed_over.begin(), dropped.passed_over.begin(), dropped.passed_over.end());
}

/// A frame the worker skipped for a newer one: its stamps travel on with the frame taken (seen, not a gap).
inline void handOnSkipped(OdometryFrame& skipped, OdometryFrame& taken) {
  taken.passed_over.insert(taken.passed_over.end(), skipped.passed_over.begin(), skipped.passed_over.end());
  taken.passed_over.push_back(skipped.msg.header().stamp.toSec());
  std::sort(taken.passed_over.begin(), taken.passed_over.end());
}

struct PreparedAhead {
  core::CameraIntrinsics camera;
  core::PreparedFrame prepared;  // prepared.done false: nothing usable (the worker converts again and reports)
};

}  // namespace ros_inputs
}  // namespace uw_multislam
