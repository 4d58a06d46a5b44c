// The offline runner's output files (the contract offline_slam --help states), written from a
// SessionManager's final state: odometry.csv, trajectory.csv, loops.csv, loop_poses.csv,
// links.csv, timing.csv, motions.csv (session,index,source: where each keyframe's odometry motion
// came from, visual / nav / fused / fallback, one row per keyframe after a session's first),
// nav_placements.csv (the nav's placements of pieces and sessions, SessionManager::addNavPlacement:
// the two keyframes, the pose and its sigmas; not in loops.csv) (and inputs.csv, the
// folders the run was made from). The CSV `session` column is the caller's numbering (offline_slam: the folder's
// position on the command line; a stored session: its id), given per session id.
#pragma once

#include <map>
#include <string>
#include <vector>

#include "uw_multislam/core/common/atomic_file.h"
#include "uw_multislam/core/common/stage_timer.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/session/session_manager.h"

namespace uw_multislam {
namespace core {

/// Writes every file into `out_dir` (which must exist). `csv_of` numbers each session id for the
/// CSV files (sessions not in it keep their id). Maps are labelled by their first session's CSV
/// number, except when that number is shared by an earlier session (pieces of one folder after a
/// tracking loss): such maps take numbers after `first_free_label`. Throws DatasetError when a
/// file cannot be written. Each file is written atomically (core/common/atomic_file.h) with
/// `modes.file` (outputModesOf(the store): a 0600 store gives 0600 files).
void writeRunOutputs(const std::string& out_dir, const SessionQueries& manager, const std::map<int, int>& csv_of,
                     int first_free_label, const StageTimes& times, const OutputModes& modes = OutputModes());

/// Creates `out_dir` and writes inputs.csv (session,folder,frames,first_stamp_s,last_stamp_s,altitude_mean_m):
/// one row per dataset folder, numbered from `first_number`, so that evaluate.py can refuse to score
/// the run against other folders. The altitude mean is over the finite altitudes (nan when none).
/// With `config_yaml` (slamConfigToYaml of the run's configuration) also config.yaml. Directories
/// it creates get `modes.directory`, files `modes.file`.
void writeRunInputs(const std::string& out_dir, const std::vector<Dataset>& datasets, int first_number,
                    const std::string& config_yaml = "", const OutputModes& modes = OutputModes());

}  // namespace core
}  // namespace uw_multislam
