#include "uw_multislam/core/frontend/dataset.h"

#include "uw_multislam/core/common/yaml_map_reader.h"
#include "uw_multislam/core/frontend/camera_model.h"
#include "uw_multislam/core/frontend/image_file.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <map>
#include <regex>
#include <set>
#include <sstream>

namespace uw_multislam {
namespace core {

namespace fs = std::filesystem;

namespace {

// A spreadsheet saving "CSV UTF-8" (or an editor) starts a file with a UTF-8 byte-order mark: not
// part of its first line.
void dropByteOrderMark(std::string* first_line) {
  if (first_line->compare(0, 3, "\xEF\xBB\xBF") == 0) first_line->erase(0, 3);
}

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r\n");
  if (b == std::string::npos) return "";
  const auto e = s.find_last_not_of(" \t\r\n");
  return s.substr(b, e - b + 1);
}

std::vector<std::string> splitCsv(const std::string& line) {
  std::vector<std::string> out;
  std::stringstream ss(line);
  std::string cell;
  while (std::getline(ss, cell, ',')) out.push_back(trim(cell));
  if (!line.empty() && line.back() == ',') out.emplace_back();
  return out;
}

[[noreturn]] void fail(const std::string& path, int line, const std::string& what) {
  std::ostringstream os;
  os << path;
  if (line > 0) os << ":" << line;
  os << ": " << what;
  throw DatasetError(os.str());
}

double parseDouble(const std::string& s, const std::string& path, int line, const char* column) {
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  // strtod also reads C's hexadecimal ("0x10" is 16): no sensor log writes that, a typo might.
  if (s.empty() || end == s.c_str() || *end != '\0' || s.find_first_of("xX") != std::string::npos)
    fail(path, line, std::string("bad number in ") + column + ": '" + s + "'");
  return v;
}

int parseInt(const std::string& s, const std::string& path, int line, const char* column) {
  char* end = nullptr;
  const long v = std::strtol(s.c_str(), &end, 10);
  if (s.empty() || end == s.c_str() || *end != '\0' || v < 0 || v > 100000000) {
    fail(path, line, std::string("bad ") + column + ": '" + s + "' (expected a non-negative integer)");
  }
  return static_cast<int>(v);
}

// Reads a CSV with the expected header; calls row(cells, line_number) for each non-empty row.
template <typename F>
void readCsv(const std::string& path, const std::vector<std::string>& header, F row) {
  std::string expected;
  for (const auto& c : header) expected += (expected.empty() ? "" : ",") + c;
  std::ifstream in(path);
  if (!in) fail(path, 0, "cannot open");
  std::string line;
  if (!std::getline(in, line)) fail(path, 0, "empty file (expected header '" + expected + "')");
  dropByteOrderMark(&line);
  if (splitCsv(trim(line)) != header) {
    fail(path, 1, "unexpected header '" + trim(line) + "' (expected '" + expected + "')");
  }
  int n = 1;
  while (std::getline(in, line)) {
    ++n;
    if (trim(line).empty()) continue;
    const auto cells = splitCsv(trim(line));
    if (cells.size() != header.size()) {
      fail(path, n, "expected " + std::to_string(header.size()) + " columns, found " + std::to_string(cells.size()));
    }
    row(cells, n);
  }
}

// Why an image entry of frames.csv is not a path inside its folder, from its text alone ("" when
// it may be): an absolute path, or one climbing above the folder with "..".
std::string entryLeavesTheFolder(const std::string& image) {
  const fs::path p(image);
  if (p.has_root_name() || p.has_root_directory()) return "is an absolute path";
  const fs::path normal = p.lexically_normal();
  if (!normal.empty() && *normal.begin() == "..") return "climbs above the folder ('..')";
  return "";
}

// `path` lies in `folder` (both real paths: no link, no "." or "..").
bool isInside(const fs::path& path, const fs::path& folder) {
  return std::mismatch(folder.begin(), folder.end(), path.begin(), path.end()).first == folder.end();
}

// Why the image at `image` cannot be a frame of the folder whose real path is `folder`, or "" when
// it can: it must exist, resolve (links followed) inside the folder, and be a regular file. Only
// looked at (stat), never opened: a FIFO would block the reader.
std::string imageEntryProblem(const fs::path& folder, const fs::path& image) {
  std::error_code ec;
  const fs::file_status st = fs::status(image, ec);
  if (st.type() == fs::file_type::not_found) {
    std::error_code lec;
    return fs::is_symlink(fs::symlink_status(image, lec)) ? "is a symbolic link to a missing file" : "does not exist";
  }
  if (ec) return "cannot be examined (" + ec.message() + ")";
  const fs::path real = fs::canonical(image, ec);
  if (ec) return "cannot be resolved (" + ec.message() + ")";
  if (!isInside(real, folder))
    return "resolves to " + real.string() + ", outside the folder " + folder.string() +
           " (an image entry must stay inside its folder)";
  if (st.type() != fs::file_type::regular) return "is " + fileTypeName(st.type()) + ", not an image file";
  return "";
}

}  // namespace

std::string distortionModelName(DistortionModel m) {
  switch (m) {
    case DistortionModel::kPlumbBob:
      return "plumb_bob";
    case DistortionModel::kRationalPolynomial:
      return "rational_polynomial";
    default:
      return "none";
  }
}

bool parseDistortionModel(const std::string& name, DistortionModel* m) {
  for (const DistortionModel c :
       {DistortionModel::kNone, DistortionModel::kPlumbBob, DistortionModel::kRationalPolynomial}) {
    if (name == distortionModelName(c)) {
      *m = c;
      return true;
    }
  }
  return false;
}

std::string CameraIntrinsics::validate() const {
  std::ostringstream os;
  const std::size_t n = distortion.size();
  if (width <= 0 || height <= 0) {
    os << "image size " << width << "x" << height << " is not positive";
  } else if (!(std::isfinite(fx) && fx > 0.0) || !(std::isfinite(fy) && fy > 0.0)) {
    os << "focal length fx=" << fx << " fy=" << fy << " must be positive";
  } else if (fx < 1.0 || fy < 1.0) {
    os << "focal length fx=" << fx << " fy=" << fy << " is below one pixel (a field of view of 180 degrees)";
  } else if (!std::isfinite(cx) || !std::isfinite(cy)) {
    os << "principal point cx=" << cx << " cy=" << cy << " is not finite";
  } else if (cx < 0.0 || cx > width || cy < 0.0 || cy > height) {
    os << "principal point cx=" << cx << " cy=" << cy << " is outside the " << width << "x" << height << " image";
  } else if ((distortion_model == DistortionModel::kNone && n != 0) ||
             (distortion_model == DistortionModel::kPlumbBob && n != 4 && n != 5) ||
             (distortion_model == DistortionModel::kRationalPolynomial && n != 8)) {
    os << "distortion model " << distortionModelName(distortion_model) << " with " << n
       << " coefficients (plumb_bob takes 4 or 5, rational_polynomial 8, none 0)";
  } else if (!std::all_of(distortion.begin(), distortion.end(), [](double d) { return std::isfinite(d); })) {
    os << "a distortion coefficient is not finite";
  }
  return os.str();
}

bool CameraIntrinsics::distorted() const {
  return std::any_of(distortion.begin(), distortion.end(), [](double d) { return d != 0.0; });
}

CameraIntrinsics CameraIntrinsics::pinhole() const {
  CameraIntrinsics c = *this;
  c.distortion_model = DistortionModel::kNone;
  c.distortion.clear();
  return c;
}

bool CameraIntrinsics::operator==(const CameraIntrinsics& o) const {
  return width == o.width && height == o.height && fx == o.fx && fy == o.fy && cx == o.cx && cy == o.cy &&
         distortion_model == o.distortion_model && distortion == o.distortion;
}

std::string Dataset::imagePath(const FrameRecord& f) const { return (fs::path(directory) / f.image).string(); }

CameraIntrinsics readCameraYaml(const std::string& path) {
  std::ifstream in(path);
  if (!in) fail(path, 0, "cannot open");
  const std::string text = readTextFile(path);
  if (text.find("camera_matrix") != std::string::npos) {
    try {
      return parseRosCalibrationYaml(text, path);
    } catch (const std::invalid_argument& e) {
      throw DatasetError(e.what());
    }
  }
  std::map<std::string, std::string> kv;
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    if (n == 1) dropByteOrderMark(&line);
    const auto hash = line.find('#');
    if (hash != std::string::npos) line = line.substr(0, hash);
    if (trim(line).empty() || trim(line).rfind("%YAML", 0) == 0 || trim(line) == "---") continue;
    const auto colon = line.find(':');
    if (colon == std::string::npos) fail(path, n, "expected 'key: value', found '" + trim(line) + "'");
    kv[trim(line.substr(0, colon))] = trim(line.substr(colon + 1));
  }
  auto get = [&](const char* key) {
    const auto it = kv.find(key);
    if (it == kv.end()) fail(path, 0, std::string("missing key '") + key + "'");
    return parseDouble(it->second, path, 0, key);
  };
  CameraIntrinsics c;
  const double w = get("image_width"), h = get("image_height");
  if (!(w >= 1 && w <= 1e6 && h >= 1 && h <= 1e6) || w != std::floor(w) || h != std::floor(h)) {
    fail(path, 0, "image size must be whole numbers of pixels in [1, 1000000]");
  }
  c.width = static_cast<int>(w);
  c.height = static_cast<int>(h);
  c.fx = get("fx");
  c.fy = get("fy");
  c.cx = get("cx");
  c.cy = get("cy");
  const std::string bad = c.validate();
  if (!bad.empty()) fail(path, 0, bad);
  return c;
}

void writeCameraYaml(const std::string& path, const CameraIntrinsics& c) {
  std::ofstream out(path);
  if (!out) throw DatasetError(path + ": cannot write");
  if (c.distorted()) {
    out << rosCalibrationYaml(c);
    if (!out) throw DatasetError(path + ": write failed");
    return;
  }
  out << std::setprecision(10) << "image_width: " << c.width << "\nimage_height: " << c.height << "\nfx: " << c.fx
      << "\nfy: " << c.fy << "\ncx: " << c.cx << "\ncy: " << c.cy << "\n";
  if (!out) throw DatasetError(path + ": write failed");
}

std::vector<FrameRecord> readFramesCsv(const std::string& path, StampOrder order) {
  std::vector<FrameRecord> frames;
  std::set<int> seen;
  readCsv(path, {"index", "image", "stamp_s", "altitude_m"}, [&](const std::vector<std::string>& c, int n) {
    FrameRecord f;
    f.index = parseInt(c[0], path, n, "index");
    f.image = c[1];
    if (f.image.empty()) fail(path, n, "empty image name");
    if (const std::string bad = entryLeavesTheFolder(f.image); !bad.empty())
      fail(path, n, "image '" + f.image + "' " + bad + ": an image entry is a file inside the folder");
    f.stamp_s = parseDouble(c[2], path, n, "stamp_s");
    f.altitude_m = parseDouble(c[3], path, n, "altitude_m");
    if (!seen.insert(f.index).second) fail(path, n, "duplicate index " + c[0]);
    // For a SLAM run one folder is one camera stream: its stamps go forward, without a gap of hours
    // (two missions in one folder). Either is refused with the line and the fix (the live odometry
    // skips a late frame and starts a session at a jump; offline the folder says what it is).
    // folder_to_bag reads them as they are (it writes such bags on purpose, counted).
    // A frame without a time (nan, inf) cannot be placed in the stream nor stored (a store's
    // keyframes need their stamp): refused here, before anything runs or is written.
    if (order == StampOrder::kRequired && !std::isfinite(f.stamp_s))
      fail(path, n, "stamp_s is not finite: '" + c[2] + "' (every frame needs its time)");
    if (order == StampOrder::kRequired && !frames.empty()) {
      const double step = f.stamp_s - frames.back().stamp_s;
      std::ostringstream os;
      if (!(step > 0)) {
        os << "stamp_s " << c[2] << " is not after the previous frame's (" << frames.back().stamp_s
           << "): frames must be in stamp order";
        fail(path, n, os.str());
      }
      if (step > kMaxFrameGapS) {
        os << "stamp_s jumps by " << step << " s (more than " << kMaxFrameGapS
           << " s): two missions in one folder? give each its own folder";
        fail(path, n, os.str());
      }
    }
    frames.push_back(f);
  });
  return frames;
}

void writeFramesCsv(const std::string& path, const std::vector<FrameRecord>& frames) {
  std::ofstream out(path);
  if (!out) throw DatasetError(path + ": cannot write");
  out << "index,image,stamp_s,altitude_m\n" << std::fixed;
  for (const auto& f : frames) {
    out << f.index << "," << f.image << "," << std::setprecision(6) << f.stamp_s << "," << std::setprecision(4)
        << f.altitude_m << "\n";
  }
  if (!out) throw DatasetError(path + ": write failed");
}

std::vector<GroundTruthRecord> readGroundTruthCsv(const std::string& path) {
  std::vector<GroundTruthRecord> gt;
  readCsv(path, {"index", "image", "x_m", "y_m", "yaw_rad"}, [&](const std::vector<std::string>& c, int n) {
    GroundTruthRecord g;
    g.index = parseInt(c[0], path, n, "index");
    g.image = c[1];
    g.pose = Pose2(parseDouble(c[2], path, n, "x_m"), parseDouble(c[3], path, n, "y_m"),
                   parseDouble(c[4], path, n, "yaw_rad"));
    gt.push_back(g);
  });
  return gt;
}

void writeGroundTruthCsv(const std::string& path, const std::vector<GroundTruthRecord>& gt) {
  std::ofstream out(path);
  if (!out) throw DatasetError(path + ": cannot write");
  out << "index,image,x_m,y_m,yaw_rad\n" << std::fixed;
  for (const auto& g : gt) {
    out << g.index << "," << g.image << "," << std::setprecision(6) << g.pose.x() << "," << g.pose.y() << ","
        << std::setprecision(7) << g.pose.yaw() << "\n";
  }
  if (!out) throw DatasetError(path + ": write failed");
}

std::vector<NavRecord> readNavCsv(const std::string& path) {
  std::vector<NavRecord> nav;
  const std::vector<std::string> header = {"stamp_s", "x_m", "y_m", "yaw_rad", "sigma_xy_m", "sigma_yaw_rad"};
  readCsv(path, header, [&](const std::vector<std::string>& c, int n) {
    double v[6];
    for (int i = 0; i < 6; ++i) {
      v[i] = parseDouble(c[i], path, n, header[i].c_str());
      if (!std::isfinite(v[i])) fail(path, n, header[i] + " is not finite: '" + c[i] + "'");
    }
    if (v[4] < 0 || v[5] < 0) fail(path, n, "sigma_xy_m and sigma_yaw_rad must be >= 0");
    if (!nav.empty() && !(v[0] > nav.back().stamp_s))
      fail(path, n, "stamp " + c[0] + " is not after the previous row's (stamps must increase)");
    nav.push_back({v[0], Pose2(v[1], v[2], v[3]), v[4], v[5]});
  });
  if (nav.empty()) fail(path, 0, "no rows");
  return nav;
}

void writeNavCsv(const std::string& path, const std::vector<NavRecord>& nav) {
  std::ofstream out(path);
  if (!out) throw DatasetError(path + ": cannot write");
  out << "stamp_s,x_m,y_m,yaw_rad,sigma_xy_m,sigma_yaw_rad\n" << std::fixed;
  for (const auto& r : nav) {
    out << std::setprecision(6) << r.stamp_s << "," << r.pose.x() << "," << r.pose.y() << "," << std::setprecision(7)
        << r.pose.yaw() << "," << std::setprecision(6) << r.sigma_xy_m << "," << std::setprecision(7) << r.sigma_yaw_rad
        << "\n";
  }
  if (!out) throw DatasetError(path + ": write failed");
}

std::string worldConventionName(WorldConvention c) { return c == WorldConvention::kNed ? "ned" : "enu"; }

bool parseWorldConvention(const std::string& name, WorldConvention* c) {
  for (const WorldConvention w : {WorldConvention::kEnu, WorldConvention::kNed}) {
    if (name == worldConventionName(w)) {
      *c = w;
      return true;
    }
  }
  return false;
}

Pose2 swapEnuNed(const Pose2& p) { return Pose2(p.y(), p.x(), normalizeAngle(M_PI / 2 - p.yaw())); }

std::string NavFrame::validate() const {
  // A tf frame id (the live side publishes it): no spaces, no leading slash (tf2 refuses those).
  static const std::regex frame_id("[A-Za-z0-9_][A-Za-z0-9_./-]*");
  std::ostringstream os;
  if (!std::regex_match(name, frame_id)) {
    os << "name '" << name << "' must be a frame id (letters, digits, '_', '.', '/', '-'; not starting with '/')";
  } else if (has_origin && !(std::isfinite(latitude_deg) && std::abs(latitude_deg) <= 90.0)) {
    os << "latitude_deg " << latitude_deg << " must be in [-90, 90]";
  } else if (has_origin && !(std::isfinite(longitude_deg) && std::abs(longitude_deg) <= 180.0)) {
    os << "longitude_deg " << longitude_deg << " must be in [-180, 180]";
  }
  return os.str();
}

bool NavFrame::operator==(const NavFrame& o) const {
  return name == o.name && convention == o.convention && has_origin == o.has_origin &&
         (!has_origin || (latitude_deg == o.latitude_deg && longitude_deg == o.longitude_deg));
}

NavFrame readNavFrameYaml(const std::string& path) {
  try {
    return parseYamlFile(path, [&](const std::string& text) {
      const YAML::Node root = parseYaml(text, "nav_frame");
      if (root.IsMap() && root.size() == 0)
        throw std::invalid_argument("nav_frame: empty file (needs name and convention)");
      MapReader r(root, "nav_frame");
      NavFrame f;
      std::string convention;
      r.read("name", &f.name);
      r.read("convention", &convention);
      const bool has_lat = static_cast<bool>(r.child("latitude_deg")),
                 has_lon = static_cast<bool>(r.child("longitude_deg"));
      r.read("latitude_deg", &f.latitude_deg);
      r.read("longitude_deg", &f.longitude_deg);
      r.finish();
      if (f.name.empty()) r.fail("missing key 'name' (the world frame's name)");
      if (convention.empty()) r.fail("missing key 'convention' (enu or ned)");
      if (!parseWorldConvention(convention, &f.convention)) r.fail("convention '" + convention + "' is not enu or ned");
      if (has_lat != has_lon)
        r.fail(std::string("'") + (has_lat ? "latitude_deg" : "longitude_deg") + "' without '" +
               (has_lat ? "longitude_deg" : "latitude_deg") + "' (the origin takes both, or neither)");
      f.has_origin = has_lat;
      const std::string bad = f.validate();
      if (!bad.empty()) r.fail(bad);
      return f;
    });
  } catch (const std::invalid_argument& e) {
    throw DatasetError(e.what());
  }
}

void writeNavFrameYaml(const std::string& path, const NavFrame& f) {
  std::ofstream out(path);
  if (!out) throw DatasetError(path + ": cannot write");
  out << "# nav.csv's world frame (doc/dataset_format.md)\n"
      << "name: " << f.name << "\n"
      << "convention: " << worldConventionName(f.convention) << "\n";
  if (f.has_origin)
    out << std::setprecision(12) << "latitude_deg: " << f.latitude_deg << "\nlongitude_deg: " << f.longitude_deg
        << "\n";
  if (!out) throw DatasetError(path + ": write failed");
}

std::string readTextFile(const std::string& path) {
  // A directory opens as an ifstream on Linux and reads as nothing: it would pass for an empty
  // file (a --config DIR then ran on the defaults without a word).
  std::error_code ec;
  if (fs::is_directory(path, ec)) throw DatasetError(path + ": a directory, not a file");
  std::ifstream in(path);
  if (!in) throw DatasetError(path + ": cannot open");
  std::stringstream ss;
  if (in.peek() != std::ifstream::traits_type::eof()) ss << in.rdbuf();
  if (in.bad() || ss.bad()) throw DatasetError(path + ": read failed");
  return ss.str();
}

Dataset loadDataset(const std::string& directory, bool check_images_exist, StampOrder order) {
  if (!fs::is_directory(directory)) throw DatasetError(directory + ": not a directory");
  Dataset d;
  d.directory = directory;
  d.camera = readCameraYaml((fs::path(directory) / "camera.yaml").string());
  const std::string frames_path = (fs::path(directory) / "frames.csv").string();
  d.frames = readFramesCsv(frames_path, order);
  if (d.frames.empty()) throw DatasetError(frames_path + ": no frames");
  if (check_images_exist) {
    std::error_code ec;
    const fs::path real = fs::canonical(directory, ec);
    if (ec) throw DatasetError(directory + ": cannot be resolved (" + ec.message() + ")");
    for (const auto& f : d.frames) {
      if (const std::string bad = imageEntryProblem(real, d.imagePath(f)); !bad.empty())
        throw DatasetError(frames_path + ": image '" + f.image + "' of frame " + std::to_string(f.index) + " " + bad);
    }
  }
  const fs::path gt = fs::path(directory) / "gt.csv";
  if (fs::exists(gt)) d.ground_truth = readGroundTruthCsv(gt.string());
  const fs::path nav = fs::path(directory) / "nav.csv";
  const fs::path nav_frame = fs::path(directory) / "nav_frame.yaml";
  if (fs::exists(nav)) d.nav = readNavCsv(nav.string());
  if (fs::exists(nav_frame)) {
    if (d.nav.empty()) throw DatasetError(nav_frame.string() + ": no nav.csv beside it (the frame is nav.csv's)");
    d.nav_frame = readNavFrameYaml(nav_frame.string());
    // Into ENU, then z-down as every pose of the core: relative motions taken from these rows are
    // then the camera's, as with rows in gt.csv's frame.
    for (NavRecord& r : d.nav) r.pose = zUp(toEnu(r.pose, d.nav_frame->convention));
  }
  return d;
}

std::string checkCameraFitsImages(const Dataset& d) {
  const std::size_t n = std::min(d.frames.size(), kCameraCheckFrames);
  for (std::size_t i = 0; i < n; ++i) {
    std::string why;
    const cv::Mat image = readFrameImage(d.imagePath(d.frames[i]), &why);
    if (image.empty()) continue;
    if (image.cols == d.camera.width && image.rows == d.camera.height) return "";
    std::ostringstream os;
    os << (fs::path(d.directory) / "camera.yaml").string() << ": a camera of " << d.camera.width << "x"
       << d.camera.height << " px, but the images are " << image.cols << "x" << image.rows << " px ('"
       << d.frames[i].image << "', frame " << d.frames[i].index
       << "): every frame would be skipped; give the camera of these images (a calibration made at another "
          "resolution scales image_width, image_height, fx, fy, cx and cy by the same factor)";
    return os.str();
  }
  return "";
}

}  // namespace core
}  // namespace uw_multislam
