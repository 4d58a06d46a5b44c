// The survey's products from a session store: trajectories (TUM, KITTI, CSV with
// covariances), pose graphs (g2o) and GeoJSON tracks, per session and per map. export_survey is
// the command line around it; mosaic.h draws the photomosaics from the same SurveyExport.
//
// Frame. Everything is written in the map frame the back-end publishes (doc/frames.md):
// z up, x along the map's first keyframe's image columns, y against its rows. The
// store's poses are the camera's in image axes (z into the seabed); each is turned by
// zUp() (vehicle_frame.h): (x, y, yaw) -> (x, -y, -yaw), its covariance by F P F, F = diag(1,
// -1, -1). The store knows nothing of the camera mount, so a pose is the camera's level frame
// (= base_link with the default mount: camera at base_link looking straight down). The position
// is the seabed point under the principal point, so z = 0; the camera's altitude above it is a
// column of the CSV. A session's files hold its keyframes in its map's frame, so the sessions of
// one map overlay.
//
// The store is opened read-only (StoreAccess::kReadOnly) and never written. The poses are the
// stored ones: the optimised motions of each map as saved (a map with loops still pending
// optimisation is exported as stored, and counted in SurveyExport::pending_loops).
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include <cstdint>
#include <functional>
#include <iosfwd>
#include <stdexcept>
#include <string>
#include <vector>

#include "uw_multislam/core/common/atomic_file.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/geometry/uncertain_pose.h"

namespace uw_multislam {
namespace core {

class ExportError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// One keyframe as exported. `pose` is in its map's frame, z up (see above), with the
/// first-order covariance of the map's motions composed up to it (as
/// MultiSessionBackend::keyframeInMap computes it).
struct ExportKeyframe {
  std::int64_t session = 0;  // store id
  int keyframe = 0;
  int frame_index = 0;
  double stamp_s = 0.0;
  double altitude_m = 0.0;
  UncertainPose2 pose;
  cv::Size image_size;                  // the image the keyframe was made from
  std::vector<std::uint8_t> thumbnail;  // the store's JPEG, may be empty
  bool covariance_known = true;         // false from an offline_slam folder (run_export.h): CSV "nan"
};

/// A pose-graph edge between two keyframes of a track (indexes into ExportTrack::keyframes):
/// z is the pose of `to` in `from`, z up.
struct ExportEdge {
  enum class Kind { kOdometry, kLink, kLoop };
  int from = 0, to = 0;
  UncertainPose2 z;
  Kind kind = Kind::kOdometry;
  bool information_known = true;  // false: the measurement's covariance is unknown (g2o: a comment line)
};

/// A session or a map: its keyframes in order (a map's in chain order) and the graph the
/// back-end's sparse optimiser solves over them: odometry motions, links between sessions, and
/// the loops neither refused nor summarised by a link.
struct ExportTrack {
  std::string label;  // "session_<store id>" or "map_<store id of its first session>"
  std::string name;   // the session's name, or the map's sessions' names joined by '+'
  std::int64_t map = 0;
  std::vector<std::int64_t> sessions;  // store ids, chain order
  std::vector<ExportKeyframe> keyframes;
  std::vector<ExportEdge> edges;
};

struct SurveyExport {
  std::string store_path;
  /// The permissions of the files (and directories) exported from it: those of the store (or of
  /// the run folder's trajectory.csv), so that a 0600 store gives 0600 files (outputModesOf).
  OutputModes modes;
  std::vector<ExportTrack> sessions;  // store order, sessions without keyframes left out
  std::vector<ExportTrack> maps;
  std::vector<std::pair<std::int64_t, CameraIntrinsics>> cameras;  // per store session
  int pending_loops = 0;  // loops stored but not yet in an optimisation (their maps as stored)

  /// The camera of a store session; nullptr when unknown.
  const CameraIntrinsics* findCamera(std::int64_t session) const;
  /// The camera of a store session. Throws ExportError when unknown.
  const CameraIntrinsics& camera(std::int64_t session) const;
};

/// The slice of `map` holding `session`'s keyframes (label session_<id>, named `name`), with the
/// edges inside the slice; empty keyframes when the session is not in the map.
ExportTrack sessionSlice(const ExportTrack& map, std::int64_t session, const std::string& name);

/// Reads a store read-only. Throws StoreError (missing, corrupt, not a store: the message names
/// the file; the file is never modified) or ExportError.
SurveyExport loadSurveyExport(const std::string& store_path);

/// The geodetic origin of the map frame: WGS84 latitude and longitude of its origin, and the
/// compass heading of its x axis (degrees clockwise from true north).
struct GeoOrigin {
  double lat_deg = 0.0, lon_deg = 0.0, heading_deg = 0.0;
  double alt_m = 0.0;  // the origin's height above the WGS84 ellipsoid (the back-end's datum; exports: 0)
};
/// "LAT,LON,HEADING_DEG" -> origin; false with `why` set on a bad text or a value out of range.
bool parseGeoOrigin(const std::string& text, GeoOrigin* out, std::string* why);
/// Local east/north (metres, tangent plane at the origin) of a map-frame (z-up) point.
Eigen::Vector2d eastNorth(const GeoOrigin& origin, double x, double y);
/// WGS84 latitude/longitude (degrees) of a map-frame (z-up) point: GeographicLib's LocalCartesian
/// at the origin (exact ellipsoidal maths, no hand-written projection).
Eigen::Vector2d latLon(const GeoOrigin& origin, double x, double y);

// --- Writers. Each writes its file atomically (core/common/atomic_file.h): a temporary created
// exclusively, without following a link, in the same directory, then renamed; a reader sees the
// old file or the whole new one, never half of it; a link planted at either name never makes a
// write land elsewhere; on any error the temporary is removed and ExportError names the file.
// `mode`: the file's permissions (narrowed by the umask), SurveyExport::modes.file for exports.

/// Writes `path` (writeFileAtomically) through `fill`; fill's stream errors (and its exceptions)
/// fail the write; ExportError names the file.
void writeExportFile(const std::string& path, mode_t mode, const std::function<void(std::ostream&)>& fill);

/// TUM: "stamp x y z qx qy qz qw" per keyframe, z = 0, the quaternion a rotation by yaw about z.
void writeTum(const std::string& path, const ExportTrack& track, mode_t mode = 0666);
/// KITTI: the 3x4 matrix [R | t] per keyframe, row-major on one line, R = Rz(yaw), t = (x, y, 0).
void writeKitti(const std::string& path, const ExportTrack& track, mode_t mode = 0666);
/// CSV: stamp_s,session,keyframe,frame_index,x_m,y_m,yaw_rad,altitude_m, then the covariance
/// cov_xx,cov_xy,cov_xyaw,cov_yy,cov_yyaw,cov_yawyaw (as loop_poses.csv names them); "nan" in each
/// covariance column of a keyframe whose covariance is unknown (covariance_known false).
void writeTrackCsv(const std::string& path, const ExportTrack& track, mode_t mode = 0666);
/// g2o: "VERTEX_SE2 i x y yaw" per keyframe (i = index in the track), "FIX 0", and
/// "EDGE_SE2 i j dx dy dyaw I11 I12 I13 I22 I23 I33" per edge, the information matrix being the
/// inverse of the measurement's covariance (upper triangle). A singular covariance is an
/// ExportError naming the edge. An edge whose information is unknown (information_known false)
/// is written as a comment, "# EDGE_SE2 i j dx dy dyaw information unknown", never with invented
/// numbers; a header comment counts them.
void writeG2o(const std::string& path, const ExportTrack& track, mode_t mode = 0666);
/// GeoJSON (RFC 7946, WGS84 lon/lat): one LineString feature per session of the tracks, with
/// properties session, name, map, keyframes, first/last stamp.
void writeGeoJson(const std::string& path, const std::vector<const ExportTrack*>& sessions, const GeoOrigin& origin,
                  mode_t mode = 0666);

/// The three g2o kinds' names, for logs: "odometry", "link", "loop".
const char* edgeKindName(ExportEdge::Kind kind);

}  // namespace core
}  // namespace uw_multislam
