// The back-end's `export` service as a core request: export_survey's files (track_files.h) of one
// session, or of its whole map, read from the session store and written into a folder below the
// export root (export_root.h). Part of uw_multislam_export (GDAL, GeographicLib stay out of the
// core library).
//
// Threading: run() takes the worker's lock only to resolve the session; the store is read
// read-only (SQLite WAL: beside the writer) and the files are written without it. One export at a
// time: another one meanwhile is answered UNAVAILABLE at once.
#pragma once

#include <cstddef>
#include <mutex>
#include <string>
#include <vector>

#include "uw_multislam/core/common/status.h"
#include "uw_multislam/core/export/track_files.h"
#include "uw_multislam/core/session/session_worker.h"

namespace uw_multislam {
namespace core {

struct SessionExportRequest {
  std::string session;        // its name, or its id in digits (SessionManager::findSession)
  std::string folder;         // below the export root (relative, or absolute inside it)
  std::string origin;         // "LAT,LON,HEADING_DEG" (GeoJSON, GeoTIFF), or empty
  double resolution_m = 0.0;  // the mosaic's metres per pixel, in (0, 100]; 0: automatic
  bool mosaic = true;
  bool map = false;  // the session's whole map instead of the session
};

struct SessionExport {
  std::string directory;           // where the files went (canonical)
  std::vector<std::string> files;  // the paths written, in order
  std::string label;               // session_<id> or map_<id>, in the ids the services use
  std::string name;                // the track's name (sessions' names)
  std::size_t keyframes = 0;
};

/// The request's arguments checked and resolved without touching any session: INVALID_ARGUMENT
/// (a bad origin or resolution, a folder outside the root), FAILED_PRECONDITION (no root: exports
/// off). Fills the files' options (`origin` must outlive them) and the directory.
Status checkExportRequest(const std::string& root, const SessionExportRequest& request, TrackFilesOptions* options,
                          GeoOrigin* origin, std::string* directory);

class SessionExporter {
 public:
  /// Exports go below `root` ("" = exports off: every request FAILED_PRECONDITION).
  explicit SessionExporter(std::string root) : root_(std::move(root)) {}
  /// Creates the root folder; false with *why when it cannot (requests then fail).
  bool createRoot(std::string* why) const;
  const std::string& root() const { return root_; }
  /// The export: checkExportRequest, then the session resolved under the worker's lock
  /// (NOT_FOUND: no such session; FAILED_PRECONDITION: no store), the store read and the files
  /// written without it (FAILED_PRECONDITION: the session has no keyframe in the store yet;
  /// INTERNAL: a file or folder that cannot be written). UNAVAILABLE while another export runs.
  Status run(const SessionWorker& worker, const SessionExportRequest& request, SessionExport* out);

 private:
  const std::string root_;
  std::mutex running_;  // held by the export that runs
};

}  // namespace core
}  // namespace uw_multislam
