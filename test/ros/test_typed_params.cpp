// Every ROS parameter is read through ros_params::Params (typed_params.h): the type rules on
// XmlRpc values as the parameter server hands them over (no master needed), and the nodelets'
// options read from trees with a value of the wrong type, each refusal naming the key.
#include <gtest/gtest.h>

#include <limits>
#include <map>
#include <string>

#include "uw_multislam/ros/odometry_options.h"
#include "uw_multislam/ros/slam_params.h"
#include "uw_multislam/ros/typed_params.h"

namespace uw_multislam {
namespace {

using ros_params::fromXmlRpc;
using XmlRpc::XmlRpcValue;

// The reason a value is refused as a T ("" when it is taken).
template <typename T>
std::string refusal(const XmlRpcValue& v) {
  T out{};
  std::string why;
  return fromXmlRpc(v, &out, &why) ? "" : why;
}

template <typename T>
T taken(const XmlRpcValue& v) {
  T out{};
  std::string why;
  EXPECT_TRUE(fromXmlRpc(v, &out, &why)) << why;
  return out;
}

XmlRpcValue list() {
  XmlRpcValue v;
  v[0] = 1;
  return v;
}

TEST(TypedParams, ANumberIsANumberAndTextIsNot) {
  EXPECT_EQ(taken<double>(XmlRpcValue(2.5)), 2.5);
  EXPECT_EQ(taken<double>(XmlRpcValue(3)), 3.0);  // YAML 3 for 3.0
  EXPECT_EQ(refusal<double>(XmlRpcValue("43")), "text, not a number (write it without quotes)");
  EXPECT_EQ(refusal<double>(XmlRpcValue("43.0951")), "text, not a number (write it without quotes)");
  EXPECT_EQ(refusal<double>(XmlRpcValue("")), "text, not a number (write it without quotes)");
  EXPECT_EQ(refusal<double>(XmlRpcValue(true)), "true/false, not a number");
  EXPECT_EQ(refusal<double>(list()), "a list, not a number");
  EXPECT_EQ(refusal<double>(XmlRpcValue(std::numeric_limits<double>::quiet_NaN())), "not a finite number");
  EXPECT_EQ(refusal<double>(XmlRpcValue(std::numeric_limits<double>::infinity())), "not a finite number");
  // rosparam (PyYAML, YAML 1.1) leaves these unquoted numbers as text: they are the numbers they spell.
  EXPECT_EQ(taken<double>(XmlRpcValue("1e-06")), 1e-6);
  EXPECT_EQ(taken<double>(XmlRpcValue("1e6")), 1e6);
  EXPECT_EQ(taken<double>(XmlRpcValue("2.5e3")), 2500.0);
  EXPECT_EQ(taken<double>(XmlRpcValue("-1E+2")), -100.0);
  // PyYAML reads 1.0e-06 as a number itself: as text it was quoted.
  EXPECT_NE(refusal<double>(XmlRpcValue("1.0e-06")), "");
}

TEST(TypedParams, RosparamsNumbersLeftAsTextAreTheExponentFormsWithoutADotOrASign) {
  for (const char* text : {"1e-06", "1e6", "+1E+3", "2.5e3", ".5e3", "3.e2"})
    EXPECT_TRUE(ros_params::isRosparamNumberText(text)) << text;
  for (const char* text : {"43", "4.3", "1.0e-06", ".5e-3", "e6", "1e", "1e-6x", "0x10", "1_000", " 1e6", "nan", ""})
    EXPECT_FALSE(ros_params::isRosparamNumberText(text)) << text;
}

TEST(TypedParams, AnIntIsAWholeNumberWithinIntsRange) {
  EXPECT_EQ(taken<int>(XmlRpcValue(5)), 5);
  EXPECT_EQ(taken<int>(XmlRpcValue(5.0)), 5);  // written with a dot
  EXPECT_EQ(taken<int>(XmlRpcValue(-2.0)), -2);
  EXPECT_EQ(taken<int>(XmlRpcValue("1e3")), 1000);
  const std::string range = "not a whole number within [-2147483648, 2147483647]";
  EXPECT_EQ(refusal<int>(XmlRpcValue(5.5)), range);  // roscpp would round it to 6
  EXPECT_EQ(refusal<int>(XmlRpcValue(3e9)), range);
  EXPECT_EQ(refusal<int>(XmlRpcValue("1.5e0")), range);  // rosparam's 1.5
  EXPECT_EQ(refusal<int>(XmlRpcValue(std::numeric_limits<double>::infinity())), range);
  EXPECT_EQ(refusal<int>(XmlRpcValue("5")), "text, not a number (write it without quotes)");
  EXPECT_EQ(refusal<int>(XmlRpcValue(false)), "true/false, not a number");
}

TEST(TypedParams, ABoolIsTrueOrFalseOnly) {
  EXPECT_TRUE(taken<bool>(XmlRpcValue(true)));
  EXPECT_FALSE(taken<bool>(XmlRpcValue(false)));
  EXPECT_EQ(refusal<bool>(XmlRpcValue("true")), "text, not true or false (write it without quotes)");
  EXPECT_EQ(refusal<bool>(XmlRpcValue(1)), "a number, not true or false");
  EXPECT_EQ(refusal<bool>(XmlRpcValue(0.0)), "a number, not true or false");
}

TEST(TypedParams, TextIsTextOnly) {
  EXPECT_EQ(taken<std::string>(XmlRpcValue("raw")), "raw");
  EXPECT_EQ(taken<std::string>(XmlRpcValue("")), "");
  EXPECT_EQ(refusal<std::string>(XmlRpcValue(5)), "a number, not text (quote it)");
  EXPECT_EQ(refusal<std::string>(XmlRpcValue(1.5)), "a number, not text (quote it)");
  EXPECT_EQ(refusal<std::string>(XmlRpcValue(true)), "true/false, not text (quote it)");  // YAML 1.1's `on`
  EXPECT_EQ(refusal<std::string>(list()), "a list, not text");
}

TEST(TypedParams, AMapOfTextHoldsTextOnly) {
  using Map = std::map<std::string, std::string>;
  XmlRpcValue peers;
  peers["auv_b"] = "/auv_b/keyframe_features";
  EXPECT_EQ(taken<Map>(peers), (Map{{"auv_b", "/auv_b/keyframe_features"}}));
  peers["auv_c"] = 3;
  EXPECT_EQ(refusal<Map>(peers), "'auv_c': a number, not text (quote it)");
  EXPECT_EQ(refusal<Map>(XmlRpcValue("auv_b")), "text, not a map");
}

TEST(TypedParams, AReadTakesTheValueWhenSetKeepsTheDefaultWhenNotAndRecordsBoth) {
  XmlRpcValue tree;
  tree["node"]["rate"] = 5;  // an int for a double
  tree["node"]["deep"]["name"] = "x";
  const ros_params::Params ns(tree, "/ns");
  const ros_params::Params node = ns.child("node");
  double rate = 1.5, other = 2.5;
  std::string name = "default";
  ros_params::param(node, "rate", &rate);
  ros_params::param(node, "other", &other);
  ros_params::param(node, "deep/name", &name);
  EXPECT_EQ(rate, 5.0);
  EXPECT_EQ(other, 2.5);
  EXPECT_EQ(name, "x");
  EXPECT_EQ(node.resolve("deep/name"), "/ns/node/deep/name");
  EXPECT_TRUE(ns.has("node/deep/name"));
  EXPECT_FALSE(ns.has("node/deep/nothing"));
  EXPECT_FALSE(ns.has("node/rate/below_a_number"));
  ASSERT_EQ(ns.reads().size(), 3u);  // a child's reads are its parent's
  EXPECT_EQ(ns.reads()[0].name, "/ns/node/rate");
  EXPECT_TRUE(ns.reads()[0].set);
  EXPECT_EQ(ns.reads()[0].value, XmlRpcValue(5.0));
  EXPECT_EQ(ns.reads()[1].name, "/ns/node/other");
  EXPECT_FALSE(ns.reads()[1].set);
  EXPECT_EQ(ns.reads()[1].value, XmlRpcValue(2.5));
  // A check runs after the type's, on the value read.
  try {
    ros_params::param(
        node, "rate", &rate, [](double v) { return v < 1; }, "below 1");
    FAIL() << "a value the check refuses was taken";
  } catch (const std::invalid_argument& e) {
    EXPECT_STREQ(e.what(), "/ns/node/rate = 5: must be below 1");
  }
}

// The message a reader throws, "" when it does not.
template <typename Read>
std::string thrown(Read read) {
  try {
    read();
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

// The pipeline's namespace as slam.launch loads it, with one node's parameters.
XmlRpcValue pipeline(const std::string& node, const std::string& key, const XmlRpcValue& value) {
  XmlRpcValue tree;
  tree[node][key] = value;
  return tree;
}

std::string backendRefusal(const XmlRpcValue& tree) {
  const ros_params::Params nh(tree, "/uw_multislam");
  return thrown([&] { ros_params::backendNodeletOptions(nh, nh.child("backend_node")); });
}

TEST(TypedParams, AQuotedDatumStopsTheBackendNamingTheKey) {
  XmlRpcValue tree;
  tree["backend_node"]["datum"]["latitude_deg"] = "43";  // a quoted number: read as 0 degrees before
  tree["backend_node"]["datum"]["longitude_deg"] = 5.9307;
  EXPECT_EQ(backendRefusal(tree),
            "/uw_multislam/backend_node/datum/latitude_deg = '43': text, not a number (write it without quotes)");
  tree["backend_node"]["datum"]["latitude_deg"] = 43;  // an int where a double belongs: fine
  tree["backend_node"]["datum"]["heading_deg"] = "30.0";
  EXPECT_EQ(backendRefusal(tree),
            "/uw_multislam/backend_node/datum/heading_deg = '30.0': text, not a number (write it without quotes)");
  tree["backend_node"]["datum"]["heading_deg"] = 30.0;
  const ros_params::Params nh(tree, "/uw_multislam");
  const ros_params::BackendNodeletOptions o = ros_params::backendNodeletOptions(nh, nh.child("backend_node"));
  ASSERT_TRUE(o.frames.datum.has_value());
  EXPECT_EQ(o.frames.datum->lat_deg, 43.0);
  EXPECT_EQ(o.frames.datum->lon_deg, 5.9307);
  EXPECT_EQ(o.frames.datum->heading_deg, 30.0);
}

TEST(TypedParams, TheFixInputsParametersAreReadTypedAndInRange) {
  XmlRpcValue tree;
  tree["backend_node"]["store_path"] = "";
  const ros_params::Params defaults(tree, "/uw_multislam");
  const ros_params::BackendNodeletOptions d =
      ros_params::backendNodeletOptions(defaults, defaults.child("backend_node"));
  EXPECT_EQ(d.fix_topic, "fix");  // on by default: nothing happens until fixes come
  EXPECT_EQ(d.fix.max_dt_s, 0.5);
  EXPECT_EQ(d.fix.default_sigma_m, 0.0);
  EXPECT_EQ(d.fix.max_waiting, 32);
  tree["backend_node"]["fix"]["max_dt_s"] = 0.0;
  const std::string zero = backendRefusal(tree);
  EXPECT_EQ(zero.rfind("/uw_multislam/backend_node/fix/max_dt_s = 0", 0), 0u) << zero;
  EXPECT_NE(zero.find(": must be in (0, 60] s"), std::string::npos) << zero;
  tree["backend_node"]["fix"]["max_dt_s"] = "0.2";
  EXPECT_EQ(backendRefusal(tree),
            "/uw_multislam/backend_node/fix/max_dt_s = '0.2': text, not a number (write it without quotes)");
  tree["backend_node"]["fix"]["max_dt_s"] = 0.2;
  tree["backend_node"]["fix"]["default_sigma_m"] = -1.0;
  EXPECT_NE(backendRefusal(tree).find("/uw_multislam/backend_node/fix/default_sigma_m = -1: must be in [0, 10000]"),
            std::string::npos)
      << backendRefusal(tree);
  tree["backend_node"]["fix"]["default_sigma_m"] = 3;  // an int where a double belongs: fine
  tree["backend_node"]["fix"]["topic"] = "";           // off
  const ros_params::Params nh(tree, "/uw_multislam");
  const ros_params::BackendNodeletOptions o = ros_params::backendNodeletOptions(nh, nh.child("backend_node"));
  EXPECT_EQ(o.fix_topic, "");
  EXPECT_EQ(o.fix.max_dt_s, 0.2);
  EXPECT_EQ(o.fix.default_sigma_m, 3.0);
}

std::string odometryRefusal(const XmlRpcValue& tree) {
  const ros_params::Params nh(tree, "/uw_multislam");
  return thrown([&] { ros_params::odometryNodeletOptions(nh, nh.child("odometry_node")); });
}

std::string loopDetectorRefusal(const XmlRpcValue& tree) {
  const ros_params::Params nh(tree, "/uw_multislam");
  return thrown([&] { ros_params::loopDetectorNodeletOptions(nh.child("loop_detector_node")); });
}

TEST(TypedParams, EachNodeRefusesAValueOfAnotherTypeNamingTheKey) {
  const std::string text = ": text, not a number (write it without quotes)", number = ": a number, not text (quote it)";
  struct Case {
    std::string (*refusal)(const XmlRpcValue&);
    const char *block, *key;
    XmlRpcValue value;
    std::string expected;  // after "/uw_multislam/<block>/<key> = "; "" when taken
  };
  const Case cases[] = {
      {backendRefusal, "backend_node", "publish_tf", XmlRpcValue("true"),
       "'true': text, not true or false (write it without quotes)"},
      {backendRefusal, "backend_node", "queue_size", XmlRpcValue(10.5),
       "10.5: not a whole number within [-2147483648, 2147483647]"},
      {backendRefusal, "backend_node", "queue_size", XmlRpcValue(10.0), ""},  // whole: fine
      {backendRefusal, "backend_node", "store_path", XmlRpcValue(1), "1" + number},
      {backendRefusal, "frames", "map_frame", XmlRpcValue(7), "7" + number},
      {odometryRefusal, "odometry_node", "session_gap_s", XmlRpcValue("60"), "'60'" + text},
      {odometryRefusal, "odometry_node", "session_gap_s", XmlRpcValue(60), ""},  // an int for a double: fine
      {odometryRefusal, "odometry_node", "image_transport", XmlRpcValue(1), "1" + number},
      {odometryRefusal, "backend_node", "publish_odom_tf", XmlRpcValue(0), "0: a number, not true or false"},
      {odometryRefusal, "frames", "mount_wait_s", XmlRpcValue("2"), "'2'" + text},
      // Range and cross-checks come after the type's, with the value as read.
      {odometryRefusal, "odometry_node", "fallback_altitude", XmlRpcValue(300),
       "300: above slam/odometry/max_altitude_m (200)"},
      {loopDetectorRefusal, "loop_detector_node", "queue_size", XmlRpcValue("100"), "'100'" + text},
      {loopDetectorRefusal, "loop_detector_node", "mode", XmlRpcValue(true), "true: true/false, not text (quote it)"},
  };
  for (const Case& c : cases) {
    const std::string key = std::string("/uw_multislam/") + c.block + "/" + c.key;
    EXPECT_EQ(c.refusal(pipeline(c.block, c.key, c.value)), c.expected.empty() ? "" : key + " = " + c.expected) << key;
  }
}

TEST(TypedParams, TheSlamTreeRefusesQuotedNumbersAndBoolsNamingTheKey) {
  XmlRpcValue tree;
  tree["odometry"]["features"]["num_features"] = "500";
  std::string what = thrown([&] { ros_params::slamConfigFromXmlRpc(tree, "/uw_multislam/slam"); });
  EXPECT_NE(what.find("/uw_multislam/slam: "), std::string::npos) << what;
  EXPECT_NE(what.find("'num_features': \"500\" is quoted text"), std::string::npos) << what;
  tree["odometry"]["features"]["num_features"] = 500;
  tree["odometry"]["matching"]["mutual"] = "false";
  what = thrown([&] { ros_params::slamConfigFromXmlRpc(tree, "/uw_multislam/slam"); });
  EXPECT_NE(what.find("'mutual': \"false\" is quoted text"), std::string::npos) << what;
  // Text where text belongs, and rosparam's exponent numbers, are read.
  tree["odometry"]["matching"]["mutual"] = false;
  tree["odometry"]["enhancement"]["mode"] = "dehaze_clahe";
  tree["backend"]["iekf"]["tolerance"] = "1e-06";
  const core::SlamConfig c = ros_params::slamConfigFromXmlRpc(tree, "/uw_multislam/slam");
  EXPECT_EQ(c.odometry.features.num_features, 500);
  EXPECT_EQ(c.odometry.enhancement.mode, core::EnhancementMode::kDehazeClahe);
  EXPECT_DOUBLE_EQ(c.backend.iekf.tolerance, 1e-6);
}

}  // namespace
}  // namespace uw_multislam
