// Map joining by a single link (paper 000 §9, Algorithm 2, equations (21)-(32)).
//
// Two sessions: a previous one ending at image pe and the current one starting at image cs.
// Each global loop Z_ci^pi (image pi of the previous session seen again at image ci of the
// current one) is predicted from the unknown link L = X_cs^pe by
//   g^i(L) = X_pe^pi ⊕ L ⊕ X_ci^cs                                            (23)
// where X_pe^pi and X_ci^cs come from the two trajectories by (2). The link is estimated from
// K loops (21)(22) by an IEKF on the 3-vector L, started at the closed form of the first loop
//   L_0 = ⊖X_pe^p0 ⊕ Z_c0^p0 ⊕ ⊖X_c0^cs                                        (32)
// with an uninformative prior (the link depends on the loops only), relinearised until the
// change is below a tolerance ((29)-(31); the Jacobian (24)-(28) is J1⊕ · J2⊕ of se2.h).
#pragma once

#include <Eigen/Core>

#include <string>
#include <vector>

#include "uw_multislam/core/backend/iekf.h"
#include "uw_multislam/core/geometry/uncertain_pose.h"

namespace uw_multislam {
namespace core {

/// One global loop as map joining sees it.
struct JoinLoop {
  Pose2 pe_from_pi;  // X_pe^pi: the previous session's end seen from the loop image pi
  Pose2 ci_from_cs;  // X_ci^cs: the loop image ci seen from the current session's start
  UncertainPose2 z;  // Z_ci^pi: the loop, pose of ci in pi
};

struct JoinResult {
  UncertainPose2 link;  // X_cs^pe with its covariance
  int iterations = 0;
  double rms_residual_m = 0.0;  // of the loops' positions after the fit
};

/// d g^i / d L at `link`, the Jacobian (25) of one loop's prediction (23), as J1⊕ · J2⊕. It follows
/// the derivation: the printed (25) has a wrong entry in row 2, column 3 (doc/references.md;
/// test/core/test_map_joining.cpp compares both with numeric differentiation).
Eigen::Matrix3d joinLinkJacobian(const JoinLoop& loop, const Pose2& link);

/// Estimates the link from K >= 1 loops. Throws std::invalid_argument on no loop or an invalid
/// loop covariance.
JoinResult estimateJoinLink(const std::vector<JoinLoop>& loops, const IekfOptions& options = IekfOptions());

/// The joined trajectory (33)(34): the previous motions, the link, then the current motions.
Trajectory joinTrajectories(const Trajectory& previous, const UncertainPose2& link, const Trajectory& current);

}  // namespace core
}  // namespace uw_multislam
