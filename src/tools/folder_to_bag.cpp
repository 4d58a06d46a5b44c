// folder_to_bag: converts a dataset folder (doc/dataset_format.md) to a ROS bag that replays
// through the same nodelets as a recorded mission. No ROS master needed.
// Exit status: 0 on success (one summary line on stdout, warnings on stderr), 1 on bad input or
// a failed write (one line on stderr), 2 on a bad command line.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "cli.h"

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/ros/dataset_bag.h"

namespace core = uw_multislam::core;
namespace rb = uw_multislam::ros_bag;
namespace po = boost::program_options;
namespace tools = uw_multislam::tools;

namespace {

std::string usageText() {
  const rb::DatasetBagOptions d;
  char text[8192];
  std::snprintf(text, sizeof(text),
                "usage: folder_to_bag DATASET_DIR OUT.bag [options]\n"
                "Writes a dataset folder (frames.csv, camera.yaml, images, optional gt.csv) to a ROS bag.\n"
                "Per frame, all stamped start time + stamp_s (the bag time too):\n"
                "  %-22s sensor_msgs/Image       the image, lossless (colour bgr8, grey mono8)\n"
                "  %-22s sensor_msgs/CameraInfo  plumb_bob, zero distortion, K and P from camera.yaml\n"
                "  %-22s sensor_msgs/Range       altitude_m (ULTRASOUND, %.0f deg beam, %.1f..%.0f m);\n"
                "  %-22s                         not written for a NaN or out-of-range altitude\n"
                "  %-22s nav_msgs/Odometry       gt.csv pose in frame '%s', child the camera frame;\n"
                "  %-22s                         only when the folder has gt.csv\n"
                "and per nav.csv row (the vehicle's dead reckoning), at start time + its stamp_s:\n"
                "  %-22s nav_msgs/Odometry       base_link in 'odom', z-up, with its covariance\n"
                "options:\n"
                "  --start-time SEC          time of stamp_s = 0, seconds since the epoch (default %u)\n"
                "  --no-ground-truth         do not write the ground-truth odometry\n"
                "  --no-nav                  do not write the nav odometry\n"
                "  --camera-frame ID         frame id of Image/CameraInfo, odometry child (default '%s')\n"
                "  --altimeter-frame ID      frame id of the Range messages (default '%s')\n"
                "  --gt-frame ID             frame id of the ground-truth odometry (default '%s')\n"
                "  --image-topic NAME        (default %s)\n"
                "  --camera-info-topic NAME  (default %s)\n"
                "  --altitude-topic NAME     (default %s)\n"
                "  --gt-topic NAME           (default %s)\n"
                "  --encoding ENC            convert images to mono8, mono16, bgr8, rgb8, bgr16 or rgb16\n"
                "                            (default: as stored)\n"
                "  --image-format F          raw (sensor_msgs/Image), or jpeg / png: sensor_msgs/CompressedImage\n"
                "                            on IMAGE_TOPIC/compressed instead, as compressed_image_transport\n"
                "                            writes it (default raw)\n"
                "  --jpeg-quality Q          JPEG quality 1..100 (default %d)\n"
                "  --compression C           none, lz4 or bz2 (default none)\n"
                "  -h, --help                this text\n"
                "Exit status 0 on success, 1 on bad input or a failed write, 2 on a bad command line.",
                d.topics.image.c_str(), d.topics.camera_info.c_str(), d.topics.altitude.c_str(),
                d.altimeter.field_of_view_rad * 180.0 / M_PI, d.altimeter.min_range_m, d.altimeter.max_range_m, "",
                d.topics.ground_truth.c_str(), d.frames.ground_truth_origin.c_str(), "", d.topics.nav.c_str(),
                rb::kDefaultStartTimeSec, d.frames.camera.c_str(), d.frames.altimeter.c_str(),
                d.frames.ground_truth_origin.c_str(), d.topics.image.c_str(), d.topics.camera_info.c_str(),
                d.topics.altitude.c_str(), d.topics.ground_truth.c_str(), d.jpeg_quality);
  return text;
}

bool parseStartTime(const std::string& s, ros::Time* out) {
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (s.empty() || *end != '\0' || !std::isfinite(v) || v <= 0.0 || v >= 4294967295.0) return false;
  out->fromSec(v);
  return true;
}

bool parseImageFormat(const std::string& s, rb::ImageFormat* out) {
  if (s == "raw")
    *out = rb::ImageFormat::kRaw;
  else if (s == "jpeg")
    *out = rb::ImageFormat::kJpeg;
  else if (s == "png")
    *out = rb::ImageFormat::kPng;
  else
    return false;
  return true;
}

bool parseQuality(const std::string& s, int* out) {
  char* end = nullptr;
  const long v = std::strtol(s.c_str(), &end, 10);
  if (s.empty() || *end != '\0' || v < 1 || v > 100) return false;
  *out = static_cast<int>(v);
  return true;
}

bool parseCompression(const std::string& s, rb::BagCompression* out) {
  if (s == "none")
    *out = rb::BagCompression::kNone;
  else if (s == "lz4")
    *out = rb::BagCompression::kLz4;
  else if (s == "bz2")
    *out = rb::BagCompression::kBz2;
  else
    return false;
  return true;
}

// A one-line reason when `dir` is a directory without the files of a dataset folder; loadDataset
// reports everything else (not a directory, bad files, missing images).
std::string notADatasetFolder(const std::string& dir) {
  namespace fs = std::filesystem;
  if (!fs::is_directory(dir)) return "";
  std::string missing;
  for (const char* f : {"frames.csv", "camera.yaml"}) {
    if (!fs::exists(fs::path(dir) / f)) missing += std::string(missing.empty() ? "" : ", ") + f;
  }
  return missing.empty() ? "" : dir + ": not a dataset folder (no " + missing + ")";
}

// An option's value converted by one of the parse functions above; refused as "bad option '--NAME VALUE'".
template <typename T>
po::typed_value<std::string>* convertedBy(T* target, bool (*parse)(const std::string&, T*)) {
  return tools::checked<T>(target, [parse](const std::string& text, T* value) {
    return parse(text, value) ? std::string() : std::string("bad option '%canonical_option% %value%'");
  });
}

std::optional<int> parseArguments(int argc, char** argv, rb::DatasetBagOptions* o, std::string* dir, std::string* bag) {
  std::vector<std::string> positional;
  bool no_ground_truth = false, no_nav = false;
  tools::CommandLine cli("folder_to_bag", usageText());
  auto option = cli.add();
  option("start-time", convertedBy(&o->start_time, parseStartTime));
  option("no-ground-truth", tools::flag(&no_ground_truth));
  option("no-nav", tools::flag(&no_nav));
  option("camera-frame", po::value(&o->frames.camera));
  option("altimeter-frame", po::value(&o->frames.altimeter));
  option("gt-frame", po::value(&o->frames.ground_truth_origin));
  option("image-topic", po::value(&o->topics.image));
  option("camera-info-topic", po::value(&o->topics.camera_info));
  option("altitude-topic", po::value(&o->topics.altitude));
  option("gt-topic", po::value(&o->topics.ground_truth));
  option("encoding", po::value(&o->image_encoding));
  option("image-format", convertedBy(&o->image_format, parseImageFormat));
  option("jpeg-quality", convertedBy(&o->jpeg_quality, parseQuality));
  option("compression", convertedBy(&o->compression, parseCompression));
  cli.positional(&positional);
  if (const auto status = cli.parse(argc, argv)) return status;
  if (no_ground_truth) o->include_ground_truth = false;
  if (no_nav) o->include_nav = false;
  if (positional.size() != 2) return cli.bad("expected DATASET_DIR and OUT.bag");
  const std::string bad = o->validate();
  if (!bad.empty()) return cli.bad(bad);
  *dir = positional[0];
  *bag = positional[1];
  return std::nullopt;
}

int writeBag(const std::string& dir, const std::string& bag, const rb::DatasetBagOptions& options) {
  const std::string not_dataset = notADatasetFolder(dir);
  if (!not_dataset.empty()) {
    std::fprintf(stderr, "folder_to_bag: %s\n", not_dataset.c_str());
    return 1;
  }
  try {
    const core::Dataset dataset = core::loadDataset(dir);
    const rb::DatasetBagStats stats = rb::writeDatasetBag(dataset, options, bag);
    for (const auto& w : rb::warnings(stats)) std::fprintf(stderr, "folder_to_bag: warning: %s\n", w.c_str());
    std::printf("folder_to_bag: wrote %s\n", rb::summarize(stats, options).c_str());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "folder_to_bag: %s\n", e.what());
    return 1;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  rb::DatasetBagOptions options;
  std::string dir, bag;
  if (const auto status = parseArguments(argc, argv, &options, &dir, &bag)) return *status;
  return writeBag(dir, bag, options);
}
