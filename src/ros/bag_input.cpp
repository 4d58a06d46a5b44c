#include "uw_multislam/ros/bag_input.h"

#include <geometry_msgs/Transform.h>
#include <nav_msgs/Odometry.h>
#include <ros/names.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Range.h>
#include <tf2/buffer_core.h>
#include <tf2/exceptions.h>
#include <tf2_msgs/TFMessage.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <mutex>
#include <sstream>
#include <vector>

#include "uw_multislam/core/frontend/altitude_buffer.h"
#include "uw_multislam/core/frontend/nav_drift.h"
#include "uw_multislam/core/frontend/nav_prior.h"
#include "uw_multislam/ros/camera_mount.h"
#include "uw_multislam/ros/image_input.h"
#include "uw_multislam/ros/message_field.h"
#include "uw_multislam/ros/nav_input.h"
#include "uw_multislam/ros/sensor_conversions.h"

namespace uw_multislam {
namespace ros_bag {

namespace rc = ros_conversions;

namespace {

constexpr char kImageType[] = "sensor_msgs/Image";
constexpr char kCompressedType[] = "sensor_msgs/CompressedImage";

std::string resolve(const std::string& ns, const std::string& name) {
  if (!name.empty() && name.front() == '/') return ros::names::clean(name);
  std::string base = ns.empty() ? "/" : ns;
  if (base.front() != '/') base = "/" + base;
  return ros::names::clean(base + "/" + name);
}

// The bag's topics of type `type`, listed for an error message.
std::string topicsOfType(const std::map<std::string, std::string>& types, const std::string& type) {
  std::string list;
  for (const auto& [topic, t] : types)
    if (t == type) list += (list.empty() ? "" : ", ") + topic;
  return list.empty() ? "none" : list;
}

geometry_msgs::Transform transformMsg(double x, double y, double z, double qx, double qy, double qz, double qw) {
  geometry_msgs::Transform t;
  t.translation.x = x;
  t.translation.y = y;
  t.translation.z = z;
  t.rotation.x = qx;
  t.rotation.y = qy;
  t.rotation.z = qz;
  t.rotation.w = qw;
  return t;
}

}  // namespace

bool parseMount(const std::string& text, std::size_t n, double* out) {
  std::istringstream is(text);
  std::vector<double> v;
  std::string word;
  while (is >> word) {
    char* end = nullptr;
    const double x = std::strtod(word.c_str(), &end);
    if (*end != '\0' || !std::isfinite(x) || std::abs(x) >= 1e3) return false;
    v.push_back(x);
  }
  if (v.size() != n) return false;
  std::copy(v.begin(), v.end(), out);
  return true;
}

struct BagStream::Impl {
  std::string path;
  BagInputOptions options;
  std::vector<std::unique_ptr<rosbag::Bag>> bags;  // one dive's bags (rosbag record --split), read as one
  std::vector<rosbag::MessageInstance> images;     // the kept frames' messages, in frame order
  bool compressed = false;
  std::string image_topic, camera_info_topic, altitude_topic, nav_topic;
  core::Dataset dataset;
  core::CameraMount mount;
  std::string mount_source;
  BagInputCounts counts;
  mutable std::mutex read;  // rosbag::Bag reads are not thread-safe

  [[noreturn]] void fail(const std::string& what) const { throw BagInputError(path + ": " + what); }

  template <typename M>
  boost::shared_ptr<M> instantiate(const rosbag::MessageInstance& m) const {
    boost::shared_ptr<M> msg;
    try {
      msg = m.instantiate<M>();
    } catch (const std::exception& e) {  // rosbag::BagException, ros::serialization errors: a damaged bag
      fail("cannot read a message on " + m.getTopic() + " at " + std::to_string(m.getTime().toSec()) + " s (" +
           e.what() + "): the bag is damaged (a truncated bag may be repaired with `rosbag reindex`)");
    }
    if (!msg) fail("a message on " + m.getTopic() + " is not a " + ros::message_traits::datatype<M>());
    return msg;
  }

  // The messages of `query` in every bag, in time order.
  std::unique_ptr<rosbag::View> view(const boost::function<bool(const rosbag::ConnectionInfo*)>& query) const {
    auto v = std::make_unique<rosbag::View>();
    for (const auto& b : bags) v->addQuery(*b, query);
    return v;
  }
  void open(const std::map<std::string, std::string>& types);
  void readCamera(const std::map<std::string, std::string>& types);
  core::AltitudeBuffer readAltitudes(std::string* altimeter_frame);
  void readDvl(rosbag::View& view, core::AltitudeBuffer* buffer, std::string* altimeter_frame);
  void readMount(const std::string& camera_frame, const std::string& altimeter_frame);
  void readNav(const std::map<std::string, std::string>& types);
};

void BagStream::Impl::open(const std::map<std::string, std::string>& types) {
  image_topic = resolve(options.ns, options.image);
  camera_info_topic = resolve(options.ns, options.camera_info);
  altitude_topic = resolve(options.ns, options.altitude);
  nav_topic = resolve(options.ns, options.nav);
  const auto type_of = [&](const std::string& topic) {
    const auto it = types.find(topic);
    return it == types.end() ? std::string() : it->second;
  };
  if (type_of(image_topic) == kImageType) {
    compressed = false;
  } else if (type_of(image_topic + "/compressed") == kCompressedType) {
    compressed = true;
    image_topic += "/compressed";
  } else {
    fail("no images on " + image_topic + " (" + kImageType + ") nor " + image_topic + "/compressed (" +
         kCompressedType + "); the bag's image topics: " + topicsOfType(types, kImageType) +
         "; compressed: " + topicsOfType(types, kCompressedType) + ": pass --image-topic (or --ns for a namespace)");
  }
  if (!options.dvl_topic.empty()) {
    altitude_topic = resolve(options.ns, options.dvl_topic);
    if (type_of(altitude_topic).empty())
      fail("no messages on " + altitude_topic + " (--dvl-topic); the bag's topics: " + [&] {
        std::string list;
        for (const auto& [topic, type] : types) list += (list.empty() ? "" : ", ") + topic;
        return list;
      }());
  } else if (type_of(altitude_topic) != "sensor_msgs/Range")
    fail("no altitude (sensor_msgs/Range) on " + altitude_topic +
         "; the bag's Range topics: " + topicsOfType(types, "sensor_msgs/Range") + ": pass --altitude-topic (or --ns)");
}

void BagStream::Impl::readCamera(const std::map<std::string, std::string>& types) {
  const auto it = types.find(camera_info_topic);
  bool have = false;
  std::string why;
  if (it != types.end() && it->second == "sensor_msgs/CameraInfo") {
    const std::unique_ptr<rosbag::View> messages = view(rosbag::TopicQuery(camera_info_topic));
    for (const rosbag::MessageInstance& m : *messages) {
      const auto info = instantiate<sensor_msgs::CameraInfo>(m);
      ++counts.camera_infos;
      core::CameraIntrinsics c;
      if (!rc::cameraFromMsg(*info, false, &c, &why))
        fail("the camera_info on " + camera_info_topic + " at " + std::to_string(info->header.stamp.toSec()) +
             " s: " + why);
      if (have && c != dataset.camera)
        fail("the camera_info on " + camera_info_topic + " changes at " + std::to_string(info->header.stamp.toSec()) +
             " s (to " + rc::describeCamera(c) + "): one calibration per stream; split the bag where it changes");
      dataset.camera = c;
      have = true;
    }
  }
  if (!have && !options.camera_info_url.empty()) {
    sensor_msgs::CameraInfo info;
    if (!rc::cameraInfoFromUrl(options.camera_info_url, &info, &why) ||
        !rc::cameraFromMsg(info, false, &dataset.camera, &why))
      fail("--camera-info-url " + options.camera_info_url + ": " + why);
    have = true;
  }
  if (!have)
    fail("no camera_info (sensor_msgs/CameraInfo) on " + camera_info_topic +
         "; the bag's CameraInfo topics: " + topicsOfType(types, "sensor_msgs/CameraInfo") +
         ": pass --camera-info-topic (or --ns), or --camera-info-url FILE (a calibration file)");
}

core::AltitudeBuffer BagStream::Impl::readAltitudes(std::string* altimeter_frame) {
  core::AltitudeBufferOptions o;
  o.max_age_s = options.altitude_max_age_s;
  const std::unique_ptr<rosbag::View> readings = view(rosbag::TopicQuery(altitude_topic));
  o.capacity = readings->size() + 1;  // the whole bag's readings: every image decides with all of them
  core::AltitudeBuffer buffer(o);
  if (!options.dvl_topic.empty()) {
    readDvl(*readings, &buffer, altimeter_frame);
    return buffer;
  }
  for (const rosbag::MessageInstance& m : *readings) {
    const auto r = instantiate<sensor_msgs::Range>(m);
    if (counts.altitudes++ == 0) *altimeter_frame = r->header.frame_id;
    bool above = false;
    std::string why;
    const double a = rc::altitudeReading(*r, options.max_altitude_m, &above, &why);
    if (!std::isfinite(a)) ++counts.altitudes_refused;
    buffer.add(r->header.stamp.toSec(), a);
  }
  return buffer;
}

void BagStream::Impl::readDvl(rosbag::View& view, core::AltitudeBuffer* buffer, std::string* altimeter_frame) {
  std::unique_ptr<MessageFields> fields;
  std::vector<std::uint8_t> bytes;
  for (const rosbag::MessageInstance& m : view) {
    if (!fields) {
      fields = std::make_unique<MessageFields>(m.getDataType(), m.getMessageDefinition());
      if (!fields->ok()) fail(altitude_topic + " (" + m.getDataType() + "): " + fields->why());
    }
    bytes.resize(m.size());
    ros::serialization::OStream stream(bytes.data(), static_cast<std::uint32_t>(bytes.size()));
    try {
      m.write(stream);
    } catch (const std::exception& e) {
      fail("cannot read a message on " + altitude_topic + " (" + e.what() + "): the bag is damaged");
    }
    double altitude = 0.0, stamp = m.getTime().toSec();
    std::string why, frame = options.dvl_frame;
    const bool header = fields->hasHeader();
    if (!fields->number(bytes.data(), bytes.size(), options.dvl_field, &altitude, &why) ||
        (header && !fields->number(bytes.data(), bytes.size(), "header.stamp", &stamp, &why)) ||
        (header && frame == "header" && !fields->text(bytes.data(), bytes.size(), "header.frame_id", &frame, &why)))
      fail(altitude_topic + " (" + m.getDataType() + "): --dvl-field " + why);
    if (frame == "header") frame.clear();  // no header: the altitude is the camera's
    if (counts.altitudes++ == 0) *altimeter_frame = frame;
    // As the relay's Range, refused by the odometry: no bottom lock (<= 0), not finite, above the bound.
    if (!(std::isfinite(altitude) && altitude > 0.0 && altitude <= options.max_altitude_m)) {
      altitude = std::nan("");
      ++counts.altitudes_refused;
    }
    buffer->add(stamp, altitude);
  }
}

void BagStream::Impl::readMount(const std::string& camera_frame, const std::string& altimeter_frame) {
  geometry_msgs::Transform camera, altimeter;
  if (options.camera_mount) {
    const auto& c = *options.camera_mount;
    // As scripts/mount_publisher.py: the optical frame is the level frame turned by pi about x.
    camera = transformMsg(c[0], c[1], c[2], std::cos(c[3] / 2.0), std::sin(c[3] / 2.0), 0.0, 0.0);
    const auto a = options.altimeter_mount.value_or(std::array<double, 3>{c[0], c[1], c[2]});
    altimeter = transformMsg(a[0], a[1], a[2], 0.0, 0.0, 0.0, 1.0);
    mount_source = "the mount given (--camera-mount)";
  } else {
    tf2::BufferCore tf;
    long statics = 0;
    const std::unique_ptr<rosbag::View> messages = view(rosbag::TopicQuery(options.tf_static));
    for (const rosbag::MessageInstance& m : *messages) {
      const auto msg = m.instantiate<tf2_msgs::TFMessage>();
      if (!msg) continue;  // another type on the topic: no mount from it
      for (const auto& t : msg->transforms) statics += tf.setTransform(t, "bag", true) ? 1 : 0;
    }
    const auto lookup = [&](const std::string& frame, const char* what) {
      try {
        return tf.lookupTransform(options.base_frame, frame, ros::Time(0)).transform;
      } catch (const tf2::TransformException& e) {
        fail("no transform " + options.base_frame + " -> " + frame + " (" + what + ") in " + options.tf_static + " (" +
             std::to_string(statics) + " static transforms: " + e.what() +
             "): give the mount with --camera-mount \"X Y Z YAW\" [--altimeter-mount \"X Y Z\"] (\"0 0 0 0\": the "
             "camera at " +
             options.base_frame + ", image columns along x), or --base-frame");
      }
    };
    if (camera_frame.empty()) fail("the images have no header.frame_id: give the mount with --camera-mount");
    camera = lookup(camera_frame, "the images' frame_id");
    altimeter = altimeter_frame.empty() ? camera : lookup(altimeter_frame, "the altitude readings' frame_id");
    mount_source = options.tf_static + " " + options.base_frame + " -> " + camera_frame + ", " +
                   (altimeter_frame.empty() ? camera_frame : altimeter_frame);
  }
  std::string why;
  if (!ros_frames::mountFromTransforms(camera, altimeter, options.max_tilt_deg * M_PI / 180.0, &mount, &why))
    fail("the sensor mount (" + mount_source + "): " + why);
}

void BagStream::Impl::readNav(const std::map<std::string, std::string>& types) {
  const auto it = types.find(nav_topic);
  if (!options.read_nav || it == types.end()) return;
  if (it->second != "nav_msgs/Odometry")
    fail(nav_topic + " is a " + it->second + ", not nav_msgs/Odometry: pass --nav-topic, or --nav off");
  core::NavTrack track;
  core::NavCovarianceCheck check(options.nav_drift, options.nav_yaw_drift);
  const double restart_after_s = 1.0;  // ~nav_reorder_tolerance_s
  const std::unique_ptr<rosbag::View> messages = view(rosbag::TopicQuery(nav_topic));
  for (const rosbag::MessageInstance& m : *messages) {
    const auto msg = instantiate<nav_msgs::Odometry>(m);
    ++counts.nav_readings;
    core::NavRecord r;
    nav_msgs::Odometry enu;
    std::string why;
    // The live nav input's checks, in its order (ros/nav_input.cpp NavInput::onNav).
    bool ok = ros_inputs::navToEnu(*msg, options.odom_frame, options.base_frame, &enu, &why) &&
              rc::navFromMsg(enu, core::CameraMount(), &r, &why);
    if (ok) {
      const core::NavCovarianceCheck before = check;
      if (!track.empty() && r.stamp_s < track.rows().back().stamp_s - restart_after_s) check.reset();
      const core::NavCovarianceCheck::Result checked = check.add(r);
      ok = track.append(checked.row, &why, restart_after_s);
      if (!ok) check = before;
      counts.nav_covariance_replaced += ok && checked.replaced;
    }
    if (!ok && counts.nav_refused++ == 0)
      std::fprintf(stderr, "offline_slam: %s: nav reading at %.3f skipped: %s\n", path.c_str(),
                   msg->header.stamp.toSec(), why.c_str());
  }
  // The track holds a camera at base_link: back to base_link, then to the mounted camera.
  for (core::NavRecord r : track.rows()) {
    r.pose = core::cameraFromVehicle(core::vehicleFromCamera(r.pose, core::CameraMount()), mount);
    dataset.nav.push_back(r);
  }
}

BagStream::BagStream(const std::string& path, const BagInputOptions& options) : impl_(std::make_unique<Impl>()) {
  Impl& b = *impl_;
  b.path = path;
  b.options = options;
  b.dataset.directory = path;
  std::istringstream parts(path);  // "a_0.bag,a_1.bag": one dive in several bags
  for (std::string part; std::getline(parts, part, ',');) {
    std::error_code ec;
    if (!std::filesystem::is_regular_file(part, ec))
      b.fail((part == path ? "" : part + ": ") + "no such bag (not a regular file)");
    b.bags.push_back(std::make_unique<rosbag::Bag>());
    try {
      b.bags.back()->open(part, rosbag::bagmode::Read);
    } catch (const std::exception& e) {
      b.fail((part == path ? "" : part + ": ") + "cannot open the bag (" + e.what() +
             "): a truncated bag (a recording that was killed) may be repaired with `rosbag reindex`");
    }
  }
  std::map<std::string, std::string> types;  // topic -> message type
  for (const auto& bag : b.bags)
    for (const rosbag::ConnectionInfo* c : rosbag::View(*bag).getConnections()) {
      const auto [it, added] = types.emplace(c->topic, c->datatype);
      if (!added && it->second != c->datatype)
        b.fail(c->topic + " is a " + it->second + " in one bag and a " + c->datatype + " in another");
    }
  if (types.empty()) b.fail("the bag is empty (no topic)");
  b.open(types);
  b.readCamera(types);
  std::string altimeter_frame;
  const core::AltitudeBuffer altitudes = b.readAltitudes(&altimeter_frame);
  // The frames: every image with an altitude at its stamp (the live pairing's rule), in the bag's order.
  std::string camera_frame;
  const std::unique_ptr<rosbag::View> messages = b.view(rosbag::TopicQuery(b.image_topic));
  for (const rosbag::MessageInstance& m : *messages) {
    ++b.counts.images;
    const std_msgs::Header header = b.compressed ? b.instantiate<sensor_msgs::CompressedImage>(m)->header
                                                 : b.instantiate<sensor_msgs::Image>(m)->header;
    if (camera_frame.empty()) camera_frame = header.frame_id;
    const core::AltitudeAt a = altitudes.at(header.stamp.toSec(), true);
    if (a.status == core::AltitudeStatus::kStale || a.status == core::AltitudeStatus::kPending) {
      ++b.counts.skipped_no_altitude;
      continue;
    }
    core::FrameRecord f;
    f.index = static_cast<int>(b.counts.images - 1);
    f.stamp_s = header.stamp.toSec();
    f.altitude_m = a.altitude_m;  // NaN for an invalid reading: the odometry reuses the last valid one
    b.dataset.frames.push_back(f);
    b.images.push_back(m);
  }
  if (b.counts.images == 0) b.fail("no image messages on " + b.image_topic);
  if (b.dataset.frames.empty())
    b.fail("none of the " + std::to_string(b.counts.images) + " images has an altitude on " + b.altitude_topic +
           " within " + std::to_string(options.altitude_max_age_s) + " s of its stamp");
  b.readMount(camera_frame, altimeter_frame);
  for (core::FrameRecord& f : b.dataset.frames)
    if (std::isfinite(f.altitude_m)) f.altitude_m = core::cameraAltitude(f.altitude_m, b.mount);
  b.readNav(types);
  b.counts.frames = static_cast<long>(b.dataset.frames.size());
}

BagStream::~BagStream() = default;

const core::Dataset& BagStream::dataset() const { return impl_->dataset; }
const BagInputCounts& BagStream::counts() const { return impl_->counts; }

double BagStream::recordedS() const {
  const auto& f = impl_->dataset.frames;
  return f.empty() ? 0.0 : f.back().stamp_s - f.front().stamp_s;
}

cv::Mat BagStream::image(std::size_t i, std::string* why) const {
  const Impl& b = *impl_;
  ros_inputs::ImageMsg msg;
  try {
    std::lock_guard<std::mutex> lock(b.read);
    if (b.compressed)
      msg.compressed = b.instantiate<sensor_msgs::CompressedImage>(b.images.at(i));
    else
      msg.image = b.instantiate<sensor_msgs::Image>(b.images.at(i));
  } catch (const BagInputError& e) {
    if (why) *why = e.what();
    return cv::Mat();
  }
  cv::Mat out;
  std::string reason;
  rc::ImageRefusal refusal = rc::ImageRefusal::kNone;
  if (!ros_inputs::imageFromInput(msg, b.dataset.camera, rc::kDefaultMaxImagePixels, &out, &reason, &refusal)) {
    if (why) *why = b.path + ": image " + std::to_string(b.dataset.frames.at(i).index) + ": " + reason;
    return cv::Mat();
  }
  // A Mat over the message's own buffer (no allocation of its own, u null) would outlive the message.
  return out.u == nullptr ? out.clone() : out;
}

std::string BagStream::summary() const {
  const Impl& b = *impl_;
  const BagInputCounts& c = b.counts;
  std::ostringstream os;
  os << b.path << ": " << c.frames << " frames of " << c.images << " images on " << b.image_topic << " ("
     << c.skipped_no_altitude << " without an altitude), " << c.altitudes << " altitudes on " << b.altitude_topic
     << " (" << c.altitudes_refused << " refused), ";
  if (b.dataset.nav.empty())
    os << "no nav on " << b.nav_topic;
  else
    os << b.dataset.nav.size() << " nav readings of " << c.nav_readings << " on " << b.nav_topic << " ("
       << c.nav_covariance_replaced << " with the drift model's sigmas)";
  os << "; camera " << rc::describeCamera(b.dataset.camera) << "; mount from " << b.mount_source << "; " << recordedS()
     << " s recorded";
  return os.str();
}

}  // namespace ros_bag
}  // namespace uw_multislam
