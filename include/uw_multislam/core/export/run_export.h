// The survey of an offline_slam output folder (doc/run_outputs.md) and its dataset folders, in
// the form export_survey writes from a store (survey_export.h): export_survey --run.
//
// What the folder holds and what it does not. trajectory.csv gives the optimised keyframe poses in
// their map's frame (6 decimals), pieces.csv which session of the engine each piece of a folder
// is (its store_session column: the files are session_<that id> and map_<that id of the map's first
// session>; it is the folder's number unless a tracking loss split a folder or the run continued a
// store; a store numbers its own sessions from 1, so a store export of the same run names them
// one higher), links.csv the chain of each map and its join links,
// odometry.csv the odometry motions, loops.csv the accepted loops and loop_poses.csv their measured
// poses with covariance. The dataset folders give each keyframe's stamp, altitude, camera and
// image (matched by frame index). The folder has no covariance of the keyframe poses, of the
// odometry motions nor of the links: the CSV's covariance columns are "nan" and those g2o edges
// are comments without information (survey_export.h, writeG2o); it does not say which loops a
// join link summarised, so the g2o holds every accepted loop whose measured pose is known.
#pragma once

#include <string>
#include <vector>

#include "uw_multislam/core/export/survey_export.h"

namespace uw_multislam {
namespace core {

struct RunExport {
  SurveyExport survey;
  std::vector<std::string> dataset_dirs;  // folder of run session 0, 1, ...
  std::vector<std::string> notes;         // what the folder lacked, one line each
};

/// Reads `run_dir` and the dataset folders of its sessions (`dataset_dirs`, in the run's order;
/// empty: the folders inputs.csv names, as written). A folder that differs from the one the run
/// was made from (inputs.csv: frame count, first and last stamp) is refused. Throws ExportError
/// (or DatasetError from a folder) with a one-line reason naming the file.
RunExport loadRunExport(const std::string& run_dir, std::vector<std::string> dataset_dirs);

}  // namespace core
}  // namespace uw_multislam
