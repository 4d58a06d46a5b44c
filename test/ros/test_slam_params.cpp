// The SLAM configuration from a parameter-server tree (no master needed: the tree is built here
// as rosparam would load config/slam.yaml).
#include <gtest/gtest.h>

#include <algorithm>

#include "uw_multislam/core/common/work_queue.h"
#include "uw_multislam/ros/odometry_options.h"
#include "uw_multislam/ros/slam_params.h"

namespace uw_multislam {
namespace {

XmlRpc::XmlRpcValue tree() {
  XmlRpc::XmlRpcValue t;
  t["odometry"]["features"]["num_features"] = 321;
  t["odometry"]["features"]["contrast_threshold"] = 0.0123456789012345;
  t["odometry"]["enhancement"]["mode"] = std::string("dehaze_clahe");
  t["odometry"]["matching"]["mutual"] = false;
  t["loops"]["global"]["hash_mode"] = std::string("haloc");
  t["loops"]["global"]["projection_seed"] = 20231122;
  // PyYAML (rosparam) reads "1e-06" without a dot as a string: it must still parse as a number.
  t["backend"]["iekf"]["tolerance"] = std::string("1e-06");
  return t;
}

TEST(SlamParams, TreeBecomesTheCoreConfiguration) {
  const core::SlamConfig c = ros_params::slamConfigFromXmlRpc(tree(), "/uw_multislam/slam");
  EXPECT_EQ(c.odometry.features.num_features, 321);
  EXPECT_DOUBLE_EQ(c.odometry.features.contrast_threshold, 0.0123456789012345);  // full precision
  EXPECT_EQ(c.odometry.enhancement.mode, core::EnhancementMode::kDehazeClahe);
  EXPECT_FALSE(c.odometry.matching.mutual);
  EXPECT_EQ(c.loops.global.hash_mode, core::HashMode::kHaloc);
  EXPECT_DOUBLE_EQ(c.backend.iekf.tolerance, 1e-6);
  // Untouched keys keep the defaults.
  EXPECT_EQ(c.loops.local.min_inliers, core::LocalLoopOptions().min_inliers);
}

TEST(SlamParams, DefaultsRoundTripThroughTheParameterForm) {
  // config/slam.yaml as rosparam holds it: every key; it gives back the built-in defaults.
  const std::string yaml = core::slamConfigToYaml(core::SlamConfig());
  const core::SlamConfig c = core::slamConfigFromYaml(yaml);
  EXPECT_EQ(core::slamConfigToYaml(c), yaml);
  XmlRpc::XmlRpcValue t = tree();
  EXPECT_NE(core::slamConfigToYaml(ros_params::slamConfigFromXmlRpc(t, "x")), yaml);
}

TEST(SlamParams, UnknownKeysAndBadValuesNameTheKey) {
  XmlRpc::XmlRpcValue t = tree();
  t["odometry"]["features"]["num_featurs"] = 5;
  try {
    ros_params::slamConfigFromXmlRpc(t, "/uw_multislam/slam");
    FAIL() << "unknown key accepted";
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("/uw_multislam/slam"), std::string::npos) << what;
    EXPECT_NE(what.find("num_featurs"), std::string::npos) << what;
  }
  XmlRpc::XmlRpcValue bad = tree();
  bad["loops"]["global"]["hash_mode"] = std::string("md5");
  EXPECT_THROW(ros_params::slamConfigFromXmlRpc(bad, "x"), std::invalid_argument);
  XmlRpc::XmlRpcValue scalar = 3;
  EXPECT_THROW(ros_params::slamConfigFromXmlRpc(scalar, "x"), std::invalid_argument);
}

TEST(SlamParams, FormerPrivateNamespaceOfTheRenamedNodes) {
  // launch/slam.launch names the nodes after their executables; before, their names (and so their
  // private namespaces, config/default.yaml's blocks) were those of config/slam.yaml's sections.
  EXPECT_EQ(ros_params::formerPrivateNamespace("/uw_multislam/odometry_node"), "/uw_multislam/odometry");
  EXPECT_EQ(ros_params::formerPrivateNamespace("/uw_multislam/loop_detector_node"), "/uw_multislam/loop_detector");
  EXPECT_EQ(ros_params::formerPrivateNamespace("/uw_multislam/local_loops_node"), "/uw_multislam/local_loops");
  EXPECT_EQ(ros_params::formerPrivateNamespace("/uw_multislam/global_loops_node"), "/uw_multislam/global_loops");
  EXPECT_EQ(ros_params::formerPrivateNamespace("/uw_multislam/backend_node"), "/uw_multislam/backend");
  EXPECT_EQ(ros_params::formerPrivateNamespace("/a/b/backend_node"), "/a/b/backend");
  EXPECT_EQ(ros_params::formerPrivateNamespace("/backend_node"), "/backend");
  // Any other name had no former one: nothing to warn about.
  EXPECT_EQ(ros_params::formerPrivateNamespace("/uw_multislam/backend"), "");
  EXPECT_EQ(ros_params::formerPrivateNamespace("/uw_multislam/backend_node_3"), "");
  EXPECT_EQ(ros_params::formerPrivateNamespace("/uw_multislam/my_backend_node"), "");
  EXPECT_EQ(ros_params::formerPrivateNamespace("/uw_multislam/manager"), "");
  EXPECT_EQ(ros_params::formerPrivateNamespace("/uw_multislam/slam_node"), "");
  EXPECT_EQ(ros_params::formerPrivateNamespace("/uw_multislam/_node"), "");
  EXPECT_EQ(ros_params::formerPrivateNamespace(""), "");
}

TEST(SlamParams, YamlOfScalarsAndLists) {
  XmlRpc::XmlRpcValue t;
  t["a"] = 1;
  t["b"][0] = 2.5;
  t["b"][1] = std::string("x");
  t["b"][2] = std::string("1e-06");
  const std::string y = ros_params::xmlRpcToYaml(t);
  EXPECT_NE(y.find("a: 1"), std::string::npos) << y;
  // Text quoted, so that the core's reader refuses it where a number belongs; a number rosparam
  // left as text (1e-06: PyYAML reads YAML 1.1) is written as the number.
  EXPECT_NE(y.find("b: [2.5, \"x\", 1e-06]"), std::string::npos) << y;
}

// The worker's queue and the subscribers' queues come from the options alone (the nodelet builds
// both from them): with newest the worker's queue is deeper than ~queue_size, so that the skip
// rule chooses, and with either policy the subscribers' queues are at least that deep, so that
// roscpp does not drop images (uncounted) before the worker's queue (counted) does.
TEST(OdometryOptions, WorkerAndInputQueuesFollowTheDropPolicy) {
  for (const int queue_size : {1, 5, 40}) {
    for (const int sync_queue_size : {1, 10, 1000}) {
      ros_params::OdometryNodeletOptions o;
      o.queue_size = queue_size;
      o.sync_queue_size = sync_queue_size;
      const std::string at =
          "queue_size " + std::to_string(queue_size) + ", sync_queue_size " + std::to_string(sync_queue_size);
      o.drop_policy = "oldest";  // every frame in order: the worker's queue is ~queue_size, the oldest dropped beyond
      EXPECT_EQ(o.workerQueueSize(), static_cast<std::size_t>(queue_size)) << at;
      EXPECT_EQ(o.inputQueueSize(),
                std::max(sync_queue_size, static_cast<int>(core::newestCapacity(static_cast<std::size_t>(queue_size)))))
          << at;
      EXPECT_GE(o.inputQueueSize(), 20 * queue_size) << at;
      o.drop_policy = "newest";
      EXPECT_EQ(o.workerQueueSize(), core::newestCapacity(static_cast<std::size_t>(queue_size))) << at;
      // 20 x queue_size, as ~queue_size's documentation and the start-up log line say.
      EXPECT_EQ(o.workerQueueSize(), 20u * static_cast<std::size_t>(queue_size)) << at;
      EXPECT_GE(o.inputQueueSize(), static_cast<int>(o.workerQueueSize())) << at;
      EXPECT_EQ(o.inputQueueSize(), std::max(sync_queue_size, static_cast<int>(o.workerQueueSize()))) << at;
    }
  }
}

// ~datum's frames, as backendNodeletOptions checks them once read: each refusal is an
// std::invalid_argument that names the parameter under the node's resolved ~datum.
constexpr char kDatumKey[] = "/uw_multislam/backend_node/datum";

std::string datumRefusal(const ros_frames::FrameOptions& f) {
  try {
    ros_params::checkDatumFrames(f, kDatumKey);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

// datum.test's datum (Toulon) at latitude `lat_deg`, with a UTM frame named utm.
ros_frames::FrameOptions utmAt(double lat_deg) {
  ros_frames::FrameOptions f;
  f.datum = core::GeoOrigin{lat_deg, 5.9307, 30.0};
  f.utm_frame = "utm";
  return f;
}

TEST(DatumFrames, AUtmFrameWithoutADatumIsRefusedNamingTheKey) {
  ros_frames::FrameOptions f;
  f.utm_frame = "utm";
  const std::string what = datumRefusal(f);
  EXPECT_EQ(what.rfind(std::string(kDatumKey) + "/utm_frame: ", 0), 0u) << what;
  EXPECT_NE(what.find("needs the datum"), std::string::npos) << what;
  EXPECT_THROW(ros_params::checkDatumFrames(f, kDatumKey), std::invalid_argument);
}

TEST(DatumFrames, AUtmFrameNamedAsMapOdomBaseOrEarthIsRefusedNamingTheKey) {
  // Names other than the defaults: the check compares with the configured frames.
  ros_frames::FrameOptions f = utmAt(43.0951);
  f.map_frame = "auv_map";
  f.odom_frame = "auv_odom";
  f.base_frame = "auv_base";
  f.earth_frame = "auv_earth";
  ASSERT_EQ(datumRefusal(f), "");
  for (const std::string& clash : {f.map_frame, f.odom_frame, f.base_frame, f.earth_frame}) {
    ros_frames::FrameOptions bad = f;
    bad.utm_frame = clash;
    const std::string what = datumRefusal(bad);
    EXPECT_EQ(what.rfind(std::string(kDatumKey) + "/utm_frame: ", 0), 0u) << clash << ": " << what;
    EXPECT_NE(what.find("must differ"), std::string::npos) << clash << ": " << what;
    EXPECT_THROW(ros_params::checkDatumFrames(bad, kDatumKey), std::invalid_argument) << clash;
  }
}

TEST(DatumFrames, AnEarthFrameNamedAsMapOdomOrBaseIsRefusedNamingTheKey) {
  ros_frames::FrameOptions f;
  ASSERT_EQ(datumRefusal(f), "");
  for (const std::string& clash : {f.map_frame, f.odom_frame, f.base_frame}) {
    ros_frames::FrameOptions bad = f;
    bad.earth_frame = clash;
    const std::string what = datumRefusal(bad);
    EXPECT_EQ(what.rfind(std::string(kDatumKey) + "/earth_frame: ", 0), 0u) << clash << ": " << what;
    EXPECT_THROW(ros_params::checkDatumFrames(bad, kDatumKey), std::invalid_argument) << clash;
  }
}

TEST(DatumFrames, APolarDatumWithAUtmFrameIsRefusedNamingTheKey) {
  // UTM spans latitudes [-80, 84) (core::utmFromMap): beyond, the zone would be UPS, which is not
  // published. Before, the parameters passed and publishDatum threw after the store was opened,
  // with a message that did not name the key.
  for (const double lat : {85.0, -82.0}) {
    const std::string what = datumRefusal(utmAt(lat));
    EXPECT_EQ(what.rfind(std::string(kDatumKey) + "/utm_frame: ", 0), 0u) << lat << ": " << what;
    EXPECT_NE(what.find("outside UTM"), std::string::npos) << lat << ": " << what;
    EXPECT_THROW(ros_params::checkDatumFrames(utmAt(lat), kDatumKey), std::invalid_argument) << lat;
  }
  // Just inside UTM's latitudes a UTM frame is published; a polar datum without one keeps its earth -> map.
  EXPECT_EQ(datumRefusal(utmAt(83.5)), "");
  EXPECT_EQ(datumRefusal(utmAt(-79.5)), "");
  ros_frames::FrameOptions polar = utmAt(85.0);
  polar.utm_frame.clear();
  EXPECT_EQ(datumRefusal(polar), "");
}

}  // namespace
}  // namespace uw_multislam
