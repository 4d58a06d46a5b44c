#include "uw_multislam/core/export/session_export.h"

#include <cmath>
#include <filesystem>

#include "uw_multislam/core/export/export_root.h"

namespace uw_multislam {
namespace core {

Status checkExportRequest(const std::string& root, const SessionExportRequest& r, TrackFilesOptions* options,
                          GeoOrigin* origin, std::string* directory) {
  std::string why;
  if (!r.origin.empty() && !parseGeoOrigin(r.origin, origin, &why))
    return {StatusCode::kInvalidArgument, "bad origin '" + r.origin + "': " + why};
  options->origin = r.origin.empty() ? nullptr : origin;
  if (!std::isfinite(r.resolution_m) || r.resolution_m < 0.0 || r.resolution_m > 100.0)
    return {StatusCode::kInvalidArgument,
            "resolution_m " + std::to_string(r.resolution_m) + ": metres per pixel in (0, 100], or 0 for automatic"};
  options->mosaic = r.mosaic;
  options->mosaic_options.resolution_m = r.resolution_m;
  if (root.empty()) return {StatusCode::kFailedPrecondition, "no export root (~export_root is empty): exports are off"};
  if (!resolveExportFolder(root, r.folder, directory, &why)) return {StatusCode::kInvalidArgument, why};
  return Status::Ok();
}

bool SessionExporter::createRoot(std::string* why) const {
  if (root_.empty()) return true;
  std::error_code ec;
  std::filesystem::create_directories(root_, ec);
  if (ec) *why = "cannot create " + root_ + " (" + ec.message() + ")";
  return !ec;
}

Status SessionExporter::run(const SessionWorker& worker, const SessionExportRequest& request, SessionExport* out) {
  std::unique_lock<std::mutex> one(running_, std::try_to_lock);
  if (!one.owns_lock()) return {StatusCode::kUnavailable, "another export is running: try again when it has answered"};
  TrackFilesOptions options;
  GeoOrigin origin;
  std::string directory;
  if (const Status st = checkExportRequest(root_, request, &options, &origin, &directory); !st.ok()) return st;
  std::string name, label, store;
  const Status found = worker.locked([&](const SessionQueries& m) -> Status {
    const int id = m.findSession(request.session);
    if (id < 0)
      return {StatusCode::kNotFound,
              "no session named or numbered '" + request.session + "' (list_sessions shows them)"};
    if (!m.hasStore())
      return {StatusCode::kFailedPrecondition, "no session store (~store_path is empty): nothing to export from"};
    name = m.name(id);
    label = request.map ? "map_" + std::to_string(m.mapOf(id)) : "session_" + std::to_string(id);
    store = m.storePath();
    return Status::Ok();
  });
  if (!found.ok()) return found;
  try {  // without the worker's lock: the store read-only, the files written
    const SurveyExport survey = loadSurveyExport(store);
    const ExportTrack* session = nullptr;
    for (const ExportTrack& t : survey.sessions)
      if (t.name == name) session = &t;
    if (!session) return {StatusCode::kFailedPrecondition, "session '" + name + "' has no keyframe in the store yet"};
    ExportTrack track = *session;
    if (request.map)
      for (const ExportTrack& m : survey.maps)
        for (std::int64_t s : m.sessions)
          if (s == session->sessions.front()) track = m;
    track.label = label;  // the ids the services use (the store's own ids differ)
    std::error_code ec;
    std::filesystem::create_directories(directory, ec);
    if (ec) return {StatusCode::kInternal, "cannot create " + directory + ": " + ec.message()};
    const TrackFiles written = writeTrackFiles(track, survey, MosaicImages(), directory, options);
    out->directory = directory;
    out->files = written.files;
    out->label = label;
    out->name = track.name;
    out->keyframes = track.keyframes.size();
    return Status::Ok();
  } catch (const std::exception& e) {
    return {StatusCode::kInternal, std::string("export failed: ") + e.what()};
  }
}

}  // namespace core
}  // namespace uw_multislam
