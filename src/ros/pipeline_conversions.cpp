#include "uw_multislam/ros/pipeline_conversions.h"

#include <opencv2/core.hpp>

#include <cmath>
#include <sstream>

#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/ros/conversions.h"

namespace uw_multislam {
namespace ros_conversions {

namespace {

constexpr std::size_t kMaxThumbnailBytes = 4u << 20;  // Keyframe.msg: a thumbnail is a small JPEG

bool fail(std::string* why, const std::string& reason) {
  if (why) *why = reason;
  return false;
}

bool finitePose(const geometry_msgs::Pose2D& p) {
  return std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.theta);
}

}  // namespace

void toArray(const Eigen::Matrix3d& c, boost::array<double, 9>* out) {
  for (int r = 0; r < 3; ++r) {
    for (int k = 0; k < 3; ++k) (*out)[r * 3 + k] = c(r, k);
  }
}

Eigen::Matrix3d fromArray(const boost::array<double, 9>& a) {
  Eigen::Matrix3d c;
  for (int r = 0; r < 3; ++r) {
    for (int k = 0; k < 3; ++k) c(r, k) = a[r * 3 + k];
  }
  return c;
}

KeyframeData keyframeData(const core::StreamKeyframe& s) {
  const core::KeyframeInput& in = s.input;
  KeyframeData k;
  k.session = in.session;
  k.keyframe = in.keyframe;
  k.frame_index = in.frame_index;
  k.altitude_m = in.altitude_m;
  k.camera = in.camera;
  k.features = in.features;
  k.hash = in.hash;
  k.motion = in.motion;
  k.odometry_pose = in.odometry_pose;
  k.nav_placement = in.nav_placement;
  k.quality = in.keyframe == 0 ? KeyframeQuality::kFirst
              : s.fallback     ? KeyframeQuality::kFallback
                               : KeyframeQuality::kMatched;
  k.matches = s.match.matches;
  k.inliers = s.match.inliers;
  k.overlap = s.match.overlap;
  k.scale = s.match.scale;
  return k;
}

uw_multislam::Keyframe unloadSessionMsg(int session) {
  uw_multislam::Keyframe m;
  m.session = session;
  m.keyframe = -1;
  return m;
}

bool isUnloadSessionMsg(const uw_multislam::Keyframe& msg) { return msg.keyframe == -1 && msg.u_px.empty(); }

uw_multislam::Keyframe toKeyframeMsg(const KeyframeData& k, const std_msgs::Header& header) {
  uw_multislam::Keyframe m;
  m.header = header;
  m.session = k.session;
  m.keyframe = k.keyframe;
  m.frame_index = k.frame_index;
  m.altitude_m = k.altitude_m;
  m.width = static_cast<std::uint32_t>(k.camera.width);
  m.height = static_cast<std::uint32_t>(k.camera.height);
  m.fx = k.camera.fx;
  m.fy = k.camera.fy;
  m.cx = k.camera.cx;
  m.cy = k.camera.cy;
  const std::size_t n = k.features.size();
  m.u_px.resize(n);
  m.v_px.resize(n);
  m.response.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    const cv::KeyPoint& kp = k.features.keypoints[i];
    m.u_px[i] = kp.pt.x;
    m.v_px[i] = kp.pt.y;
    m.response[i] = kp.response;
  }
  const cv::Mat& d = k.features.descriptors;
  // The kind's width even with no feature (an empty n x 32 matrix still says ORB).
  m.descriptor_size = static_cast<std::uint32_t>(d.cols > 0 ? d.cols : core::descriptorBytes(core::FeatureType::kSift));
  if (!d.empty()) {
    cv::Mat bytes;
    d.convertTo(bytes, CV_8U);  // rounds and saturates
    if (!bytes.isContinuous()) bytes = bytes.clone();
    m.descriptors.assign(bytes.data, bytes.data + bytes.total());
  }
  m.hash.assign(k.hash.data(), k.hash.data() + k.hash.size());
  m.thumbnail = k.thumbnail;
  m.motion = toPose2DMsg(k.motion.mean);
  toArray(k.motion.covariance, &m.motion_covariance);
  m.odometry_pose = toPose2DMsg(k.odometry_pose);
  switch (k.quality) {
    case KeyframeQuality::kFirst:
      m.status = uw_multislam::Keyframe::FIRST;
      break;
    case KeyframeQuality::kMatched:
      m.status = uw_multislam::Keyframe::MATCHED;
      break;
    case KeyframeQuality::kFallback:
      m.status = uw_multislam::Keyframe::FALLBACK;
      break;
  }
  m.matches = k.matches;
  m.inliers = k.inliers;
  m.overlap = static_cast<float>(k.overlap);
  m.scale = static_cast<float>(k.scale);
  m.placement_session = k.nav_placement ? k.nav_placement->session : -1;
  m.placement_keyframe = k.nav_placement ? k.nav_placement->keyframe : -1;
  if (k.nav_placement) {
    m.placement = toPose2DMsg(k.nav_placement->z.mean);
    toArray(k.nav_placement->z.covariance, &m.placement_covariance);
    m.placement_visual = k.nav_placement->visual;
  }
  return m;
}

bool fromMsg(const uw_multislam::Keyframe& m, KeyframeData* out, std::string* why) {
  std::ostringstream os;
  os << "keyframe " << m.keyframe << " of session " << m.session << ": ";
  const std::string who = os.str();
  if (m.session < 0 || m.keyframe < 0) return fail(why, who + "negative session or keyframe id");
  if (m.session > core::kMaxSessionId)
    return fail(why, who + "session id past the largest, " + std::to_string(core::kMaxSessionId));
  core::CameraIntrinsics camera{static_cast<int>(m.width), static_cast<int>(m.height), m.fx, m.fy, m.cx, m.cy};
  const std::string bad_camera = camera.validate();
  if (!bad_camera.empty()) return fail(why, who + "camera: " + bad_camera);
  if (!(std::isfinite(m.altitude_m) && m.altitude_m > 0)) return fail(why, who + "altitude must be positive");
  const std::size_t n = m.u_px.size();
  if (m.v_px.size() != n || m.response.size() != n) {
    return fail(why, who + "u_px, v_px and response must have the same length");
  }
  if (m.descriptor_size != static_cast<std::uint32_t>(core::descriptorBytes(core::FeatureType::kSift)) &&
      m.descriptor_size != static_cast<std::uint32_t>(core::descriptorBytes(core::FeatureType::kOrb))) {
    return fail(why, who + "descriptor_size must be 128 (SIFT) or 32 (ORB), not " + std::to_string(m.descriptor_size));
  }
  if (m.descriptors.size() != n * m.descriptor_size) {
    return fail(why, who + "descriptors must hold n x descriptor_size bytes");
  }
  if (!m.hash.empty() && m.hash.size() != static_cast<std::size_t>(core::HalocProjections::kHashSize)) {
    return fail(why, who + "hash must have 384 values (3 x 128) or none, not " + std::to_string(m.hash.size()));
  }
  for (float v : m.hash) {
    if (!std::isfinite(v)) return fail(why, who + "non-finite hash value");
  }
  if (m.status > uw_multislam::Keyframe::FALLBACK) return fail(why, who + "unknown status");
  if (!finitePose(m.motion) || !finitePose(m.odometry_pose)) return fail(why, who + "non-finite pose");
  const Eigen::Matrix3d cov = fromArray(m.motion_covariance);
  const bool first = m.status == uw_multislam::Keyframe::FIRST;
  if (!first) {
    const std::string bad_cov = core::checkCovariance(cov);
    if (!bad_cov.empty()) return fail(why, who + "motion covariance: " + bad_cov);
  } else if (!cov.allFinite()) {
    return fail(why, who + "non-finite motion covariance");
  }
  std::optional<core::NavPlacementInput> placement;
  const Eigen::Matrix3d placement_cov = fromArray(m.placement_covariance);
  if (!placement_cov.isZero(0.0)) {  // zero: none (also what an older sender leaves)
    if (m.placement_session < 0 || m.placement_session > core::kMaxSessionId || m.placement_keyframe < 0)
      return fail(why, who + "placement names no keyframe (session " + std::to_string(m.placement_session) +
                           ", keyframe " + std::to_string(m.placement_keyframe) + ")");
    if (!finitePose(m.placement)) return fail(why, who + "non-finite placement");
    const std::string bad = core::checkCovariance(placement_cov);
    if (!bad.empty()) return fail(why, who + "placement covariance: " + bad);
    placement = core::NavPlacementInput{m.placement_session, m.placement_keyframe,
                                        core::UncertainPose2(fromMsg(m.placement), placement_cov),
                                        static_cast<bool>(m.placement_visual)};
  }
  KeyframeData k;
  k.nav_placement = placement;
  k.session = m.session;
  k.keyframe = m.keyframe;
  k.frame_index = m.frame_index;
  k.altitude_m = m.altitude_m;
  k.camera = camera;
  k.features.image_size = cv::Size(camera.width, camera.height);
  k.features.keypoints.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    if (!std::isfinite(m.u_px[i]) || !std::isfinite(m.v_px[i])) return fail(why, who + "non-finite feature position");
    cv::KeyPoint kp;
    kp.pt = cv::Point2f(m.u_px[i], m.v_px[i]);
    kp.response = m.response[i];
    k.features.keypoints.push_back(kp);
  }
  {
    // The message's bytes viewed as an n x descriptor_size matrix and turned into the extractor's
    // form: SIFT widened into new CV_32F memory; ORB's bytes copied only (the message goes).
    const int rows = static_cast<int>(n), cols = static_cast<int>(m.descriptor_size);
    const cv::Mat bytes =
        n > 0 ? cv::Mat(rows, cols, CV_8U, const_cast<std::uint8_t*>(m.descriptors.data())) : cv::Mat(0, cols, CV_8U);
    cv::Mat d = core::extractorDescriptors(bytes);
    k.features.descriptors = n > 0 && d.data == bytes.data ? d.clone() : d;
  }
  k.hash = Eigen::Map<const Eigen::VectorXf>(m.hash.data(), static_cast<Eigen::Index>(m.hash.size()));
  if (m.thumbnail.size() > kMaxThumbnailBytes)
    return fail(why, who + "thumbnail of " + std::to_string(m.thumbnail.size()) + " bytes, more than 4 MB");
  k.thumbnail = m.thumbnail;
  k.motion = first ? core::UncertainPose2::exact(core::Pose2()) : core::UncertainPose2(fromMsg(m.motion), cov);
  k.odometry_pose = fromMsg(m.odometry_pose);
  k.quality =
      first ? KeyframeQuality::kFirst
            : (m.status == uw_multislam::Keyframe::FALLBACK ? KeyframeQuality::kFallback : KeyframeQuality::kMatched);
  k.matches = m.matches;
  k.inliers = m.inliers;
  k.overlap = m.overlap;
  k.scale = m.scale;
  *out = std::move(k);
  return true;
}

uw_multislam::Loop toLoopMsg(const core::Loop& l, const std_msgs::Header& header) {
  uw_multislam::Loop m;
  m.header = header;
  m.kind = l.kind == core::Loop::Kind::kLocal ? uw_multislam::Loop::LOCAL : uw_multislam::Loop::GLOBAL;
  m.session_a = l.session_a;
  m.keyframe_a = l.keyframe_a;
  m.frame_a = l.frame_a;
  m.session_b = l.session_b;
  m.keyframe_b = l.keyframe_b;
  m.frame_b = l.frame_b;
  m.pose = toPose2DMsg(l.z.mean);
  toArray(l.z.covariance, &m.covariance);
  m.inliers = l.inliers;
  m.hash_l1 = l.hash_l1;
  return m;
}

bool fromMsg(const uw_multislam::Loop& m, core::Loop* out, std::string* why) {
  if (m.kind > uw_multislam::Loop::GLOBAL) return fail(why, "loop: unknown kind");
  if (m.session_a < 0 || m.session_b < 0 || m.keyframe_a < 0 || m.keyframe_b < 0) {
    return fail(why, "loop: negative session or keyframe id");
  }
  if (m.session_a > core::kMaxSessionId || m.session_b > core::kMaxSessionId)
    return fail(why, "loop: session id past the largest, " + std::to_string(core::kMaxSessionId));
  if (!finitePose(m.pose)) return fail(why, "loop: non-finite pose");
  const Eigen::Matrix3d cov = fromArray(m.covariance);
  const std::string bad = core::checkCovariance(cov);
  if (!bad.empty()) return fail(why, "loop: covariance: " + bad);
  core::Loop l;
  l.kind = m.kind == uw_multislam::Loop::LOCAL ? core::Loop::Kind::kLocal : core::Loop::Kind::kGlobal;
  l.session_a = m.session_a;
  l.keyframe_a = m.keyframe_a;
  l.frame_a = m.frame_a;
  l.session_b = m.session_b;
  l.keyframe_b = m.keyframe_b;
  l.frame_b = m.frame_b;
  l.z = core::UncertainPose2(fromMsg(m.pose), cov);
  l.inliers = m.inliers;
  l.hash_l1 = m.hash_l1;
  *out = l;
  return true;
}

uw_multislam::KeyframeHash toKeyframeHashMsg(const KeyframeHashData& h, const std_msgs::Header& header) {
  uw_multislam::KeyframeHash m;
  m.header = header;
  m.session = h.session;
  m.keyframe = h.keyframe;
  m.frame_index = h.frame_index;
  m.hash_mode =
      h.mode == core::HashMode::kHaloc ? uw_multislam::KeyframeHash::HALOC : uw_multislam::KeyframeHash::SORTED_DCT;
  m.projection_seed = h.projection_seed;
  m.num_features = h.num_features;
  m.features = core::featureTypeName(h.features);
  m.values.assign(h.values.data(), h.values.data() + h.values.size());
  return m;
}

bool fromMsg(const uw_multislam::KeyframeHash& m, KeyframeHashData* out, std::string* why) {
  if (m.hash_mode > uw_multislam::KeyframeHash::SORTED_DCT) return fail(why, "keyframe hash: unknown hash_mode");
  const std::size_t n = static_cast<std::size_t>(core::HalocProjections::kHashSize);
  if (m.values.empty() && !m.codes.empty()) {  // sent as 8-bit codes
    if (m.codes.size() != n) return fail(why, "keyframe hash: codes must have 384 entries (3 x 128)");
    if (!(std::isfinite(m.code_range) && m.code_range > 0))
      return fail(why, "keyframe hash: code_range must be positive");
    uw_multislam::KeyframeHash v = m;
    const Eigen::VectorXf values = core::hashFromCodes(m.codes, m.code_range);
    v.values.assign(values.data(), values.data() + values.size());
    v.codes.clear();
    return fromMsg(v, out, why);
  }
  if (m.values.size() != n) {
    return fail(why, "keyframe hash: values (or codes) must have 384 entries (3 x 128)");
  }
  if (m.num_features < 1) return fail(why, "keyframe hash: num_features must be positive");
  core::FeatureType features = core::FeatureType::kSift;  // an older sender's: SIFT was the only kind
  if (!m.features.empty() && !core::parseFeatureType(m.features, &features))
    return fail(why, "keyframe hash: unknown features '" + m.features.substr(0, 32) + "' (sift or orb)");
  if (m.session < 0 || m.session > core::kMaxSessionId || m.keyframe < 0)
    return fail(why, "keyframe hash: session id outside [0, " + std::to_string(core::kMaxSessionId) +
                         "] or negative keyframe id");
  KeyframeHashData h;
  h.session = m.session;
  h.keyframe = m.keyframe;
  h.frame_index = m.frame_index;
  h.mode = m.hash_mode == uw_multislam::KeyframeHash::HALOC ? core::HashMode::kHaloc : core::HashMode::kSortedDct;
  h.projection_seed = m.projection_seed;
  h.num_features = m.num_features;
  h.features = features;
  h.values.resize(static_cast<Eigen::Index>(m.values.size()));
  for (std::size_t i = 0; i < m.values.size(); ++i) {
    if (!std::isfinite(m.values[i])) return fail(why, "keyframe hash: non-finite value");
    h.values[static_cast<Eigen::Index>(i)] = m.values[i];
  }
  *out = std::move(h);
  return true;
}

namespace {
// The fields a Keyframe and a fleet KeyframeHash share (ids, camera, altitude, motion, pose): one
// copy for both directions.
template <class From, class To>
void copySharedFields(const From& f, To* t) {
  t->header = f.header;
  t->session = f.session;
  t->keyframe = f.keyframe;
  t->frame_index = f.frame_index;
  t->altitude_m = f.altitude_m;
  t->width = f.width;
  t->height = f.height;
  t->fx = f.fx;
  t->fy = f.fy;
  t->cx = f.cx;
  t->cy = f.cy;
  t->motion = f.motion;
  t->motion_covariance = f.motion_covariance;
  t->odometry_pose = f.odometry_pose;
}
}  // namespace

uw_multislam::KeyframeHash toFleetHashMsg(KeyframeData k, const std::string& vehicle, core::HashMode mode,
                                          std::uint64_t projection_seed, int num_features, core::FeatureType features,
                                          const std_msgs::Header& header, bool codes) {
  k.features = core::FrameFeatures();  // what crosses the link: no features, no image
  k.thumbnail.clear();
  const uw_multislam::Keyframe km = toKeyframeMsg(k, header);
  KeyframeHashData h;
  h.session = k.session;
  h.keyframe = k.keyframe;
  h.frame_index = k.frame_index;
  h.mode = mode;
  h.projection_seed = projection_seed;
  h.num_features = num_features;
  h.features = features;
  h.values = k.hash;
  uw_multislam::KeyframeHash m = toKeyframeHashMsg(h, header);
  copySharedFields(km, &m);
  m.vehicle = vehicle;
  if (codes) {
    m.code_range = core::hashCodeRange(mode);
    m.codes = core::hashCodes(k.hash, m.code_range);
    m.values.clear();
  }
  return m;
}

uw_multislam::KeyframeHash fleetSessionEndedMsg(const std::string& vehicle, int session, const ros::Time& stamp) {
  uw_multislam::KeyframeHash m;
  m.header.stamp = stamp;
  m.vehicle = vehicle;
  m.session = session;
  m.keyframe = -1;
  m.session_ended = true;
  return m;
}

bool fromFleetHashMsg(const uw_multislam::KeyframeHash& m, KeyframeData* out, KeyframeHashData* settings,
                      std::string* why) {
  if (m.session_ended) return fail(why, "fleet hash: a session-ended notice, not a keyframe");
  KeyframeHashData h;
  if (!fromMsg(m, &h, why)) return false;
  // The rest is a Keyframe without features: checked by the same rules.
  uw_multislam::Keyframe k;
  copySharedFields(m, &k);
  k.descriptor_size = static_cast<std::uint32_t>(core::HalocProjections::kDescriptorSize);
  k.hash.assign(h.values.data(), h.values.data() + h.values.size());  // from values or codes
  k.status = m.keyframe == 0 ? uw_multislam::Keyframe::FIRST : uw_multislam::Keyframe::MATCHED;
  if (!fromMsg(k, out, why)) return false;
  if (settings) *settings = std::move(h);
  return true;
}

}  // namespace ros_conversions
}  // namespace uw_multislam
