// Dataset folders (doc/dataset_format.md): frames.csv, camera.yaml, images, optional gt.csv,
// nav.csv and nav_frame.yaml.
// The project reads and writes this format: the survey generator writes it, folder_to_bag and
// offline_slam read it. Errors are reported as DatasetError with the file and line at fault.
#pragma once

#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "uw_multislam/core/geometry/se2.h"

namespace uw_multislam {
namespace core {

class DatasetError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Lens distortion models, named and ordered as a ROS CameraInfo's (and OpenCV's) D.
enum class DistortionModel {
  kNone,                // a pinhole: rectified images, or a lens without measurable distortion
  kPlumbBob,            // k1, k2, p1, p2, k3 (4 or 5 coefficients)
  kRationalPolynomial,  // k1, k2, p1, p2, k3, k4, k5, k6
};
/// "none", "plumb_bob", "rational_polynomial".
std::string distortionModelName(DistortionModel m);
/// False for any other name (ROS's "equidistant" included: rectify such images first).
bool parseDistortionModel(const std::string& name, DistortionModel* m);

/// The camera of the images, in pixels: the pinhole K (fx, fy, cx, cy) and, for raw images, the
/// lens distortion D. Only feature points are undistorted (core/frontend/camera_model.h), never
/// the image.
struct CameraIntrinsics {
  int width = 0;
  int height = 0;
  double fx = 0.0;
  double fy = 0.0;
  double cx = 0.0;
  double cy = 0.0;
  DistortionModel distortion_model = DistortionModel::kNone;
  std::vector<double> distortion{};  // D, OpenCV's order; empty for kNone

  /// Empty when usable, else a sentence naming the bad value.
  std::string validate() const;
  /// Some coefficient of D is not zero.
  bool distorted() const;
  /// 0x0: not known (a stored session without keyframes; older stores kept it for some with).
  bool unknown() const { return width == 0 && height == 0; }
  /// The same K without distortion: the camera of undistorted feature points.
  CameraIntrinsics pinhole() const;
  bool operator==(const CameraIntrinsics& o) const;
  bool operator!=(const CameraIntrinsics& o) const { return !(*this == o); }
};

/// One row of frames.csv.
struct FrameRecord {
  int index = 0;
  std::string image;  // file name relative to the folder
  double stamp_s = 0.0;
  double altitude_m = 0.0;
};

/// One row of gt.csv: the pose of the image centre in the first frame's image axes.
struct GroundTruthRecord {
  int index = 0;
  std::string image;
  Pose2 pose;
};

/// One row of nav.csv: the vehicle's dead-reckoned (DVL/INS) pose of the image centre, in the same
/// frame and conventions as gt.csv, with the standard deviations of its accumulated error
/// (sigma_xy_m of each of x and y, sigma_yaw_rad of yaw).
struct NavRecord {
  double stamp_s = 0.0;
  Pose2 pose;
  double sigma_xy_m = 0.0;
  double sigma_yaw_rad = 0.0;
};

/// The axes of a world frame (REP-103): ENU is x east, y north, z up, yaw counter-clockwise from
/// east; NED is x north, y east, z down, yaw (a heading) clockwise from north.
enum class WorldConvention { kEnu, kNed };
/// "enu", "ned".
std::string worldConventionName(WorldConvention c);
/// False for any other name.
bool parseWorldConvention(const std::string& name, WorldConvention* c);

/// REP-103's NED <-> ENU for a planar pose, (x, y, yaw) -> (y, x, pi/2 - yaw) with yaw wrapped: a
/// proper rotation in 3-D ((x, y, z) -> (y, x, -z)), its own inverse.
Pose2 swapEnuNed(const Pose2& p);
/// A pose of a world frame written in `c`, in ENU.
inline Pose2 toEnu(const Pose2& p, WorldConvention c) { return c == WorldConvention::kNed ? swapEnuNed(p) : p; }

/// nav_frame.yaml: nav.csv's poses are in this world frame, shared by every folder of a mission
/// that names it, instead of in gt.csv's frame (doc/dataset_format.md).
struct NavFrame {
  std::string name;                                    // the frame's name (a tf frame id)
  WorldConvention convention = WorldConvention::kEnu;  // as nav.csv is written
  bool has_origin = false;                             // latitude_deg, longitude_deg given
  double latitude_deg = 0.0;                           // WGS84 of the frame's origin (x = y = 0)
  double longitude_deg = 0.0;

  /// Empty when usable, else a sentence naming the key at fault.
  std::string validate() const;
  bool operator==(const NavFrame& o) const;
};
/// Reads nav_frame.yaml: `name` and `convention` (enu or ned) required, `latitude_deg` and
/// `longitude_deg` together or not at all, no other key; DatasetError naming the file and the key.
NavFrame readNavFrameYaml(const std::string& path);
void writeNavFrameYaml(const std::string& path, const NavFrame& frame);

struct Dataset {
  std::string directory;
  CameraIntrinsics camera;
  std::vector<FrameRecord> frames;
  std::vector<GroundTruthRecord> ground_truth;  // empty when the folder has no gt.csv
  /// nav.csv's rows in the core's conventions (image axes, z down), which is what the odometry
  /// takes relative motions from; empty when the folder has no nav.csv. Without nav_frame.yaml they
  /// are in gt.csv's frame as written. With it, they are that world frame read into ENU (NED
  /// turned by swapEnuNed) and turned z-down by zUp (geometry/vehicle_frame.h): zUp(nav[i].pose)
  /// is the row's ENU pose.
  std::vector<NavRecord> nav;
  /// Set when the folder has nav_frame.yaml: nav.csv's world frame.
  std::optional<NavFrame> nav_frame;

  /// Full path of a frame's image.
  std::string imagePath(const FrameRecord& f) const;
};

/// Reads camera.yaml in either format (doc/dataset_format.md): "key: value" lines with the six
/// keys image_width, image_height, fx, fy, cx, cy (a pinhole), or a ROS calibration YAML (the
/// camera_calibration_parsers format, recognised by its camera_matrix key; see
/// parseRosCalibrationYaml in core/frontend/camera_model.h).
CameraIntrinsics readCameraYaml(const std::string& path);
/// Writes the six-key format for a pinhole, the ROS calibration format for a distorted camera.
void writeCameraYaml(const std::string& path, const CameraIntrinsics& c);

/// The longest step between two frames' stamps in one folder (one mission): an hour.
constexpr double kMaxFrameGapS = 3600.0;
/// kRequired: frames.csv's stamps must increase by at most kMaxFrameGapS (the SLAM runs: one
/// folder is one mission); kAsWritten: read as they are (folder_to_bag, the benches).
enum class StampOrder { kAsWritten, kRequired };
/// Reads frames.csv: header "index,image,stamp_s,altitude_m", indexes unique, image entries paths
/// inside the folder (no absolute path, none climbing above it with ".."), the stamps' order
/// checked as `order` says (DatasetError naming the line). Altitudes are read as written (NaN or
/// negative values are the consumer's to reject), as are non-finite stamps.
std::vector<FrameRecord> readFramesCsv(const std::string& path, StampOrder order = StampOrder::kAsWritten);
void writeFramesCsv(const std::string& path, const std::vector<FrameRecord>& frames);

std::vector<GroundTruthRecord> readGroundTruthCsv(const std::string& path);
void writeGroundTruthCsv(const std::string& path, const std::vector<GroundTruthRecord>& gt);

/// Reads nav.csv: header "stamp_s,x_m,y_m,yaw_rad,sigma_xy_m,sigma_yaw_rad", every value finite,
/// sigmas >= 0, stamps strictly increasing, at least one row; DatasetError with the line otherwise.
std::vector<NavRecord> readNavCsv(const std::string& path);
void writeNavCsv(const std::string& path, const std::vector<NavRecord>& nav);

/// The whole content of a text file; throws DatasetError("<path>: cannot open") when unreadable.
std::string readTextFile(const std::string& path);

/// Loads a dataset folder; throws DatasetError with a one-line reason when it is not one
/// (missing files, bad header, unparsable number, duplicate index). With check_images_exist, each
/// image entry must be a regular file whose real path (links followed) lies inside the folder's
/// real path: one missing, outside (a link out of the folder), a directory or a FIFO is refused
/// naming what it is, without opening it. nav.csv
/// is read when present; it must cover the stamps of the frames it is used for (see NavTrack).
/// nav_frame.yaml is read when present and needs nav.csv beside it.
Dataset loadDataset(const std::string& directory, bool check_images_exist = true,
                    StampOrder order = StampOrder::kAsWritten);

/// The frames checkCameraFitsImages reads at most to find one image that decodes.
constexpr std::size_t kCameraCheckFrames = 20;
/// Why the folder's camera.yaml is not its images' camera ("" when it is): the first image that reads
/// (readFrameImage; among the first kCameraCheckFrames frames) has another size than camera.yaml
/// says, so a SLAM run would skip every frame. "" also when none of those frames reads (those are
/// the run's counted skips).
std::string checkCameraFitsImages(const Dataset& d);

}  // namespace core
}  // namespace uw_multislam
