// An absolute position prior on one keyframe of a map: a GPS at the surface or a USBL fix, placed
// in the map's frame through its datum (core/export/geo_datum.h), with its covariance. Both
// optimisers take it (MapGraph::priors): the pose graph as a unary residual, the IEKF as a
// measurement of the keyframe's position.
#pragma once

#include <Eigen/Core>

#include <string>

namespace uw_multislam {
namespace core {

struct PositionPrior {
  int index = 0;                                             // the keyframe, along the map's chain
  Eigen::Vector2d position = Eigen::Vector2d::Zero();        // its (x, y) in the map's frame, m
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Identity();  // m^2
};

/// Why a prior cannot be used with `n` keyframes (index outside [1, n - 1]: keyframe 0 is the
/// map's frame; a position or covariance not finite; a covariance not symmetric positive
/// definite), or "".
std::string checkPositionPrior(const PositionPrior& p, int n);

}  // namespace core
}  // namespace uw_multislam
