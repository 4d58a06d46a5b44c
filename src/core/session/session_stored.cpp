// The session manager's stored sessions: reload, unload and delete.
#include "uw_multislam/core/session/session_manager.h"

#include <stdexcept>
#include <utility>

#include "session_detail.h"

namespace uw_multislam {
namespace core {

using namespace session_detail;  // NOLINT: the manager's own helpers

Status SessionManager::reload(const std::string& name_or_id, ReloadedSession* out, ReloadRead read) {
  if (!table_.store()) return {StatusCode::kFailedPrecondition, "no session store: nothing to reload"};
  const int id = table_.findSession(name_or_id);
  if (id < 0 || table_.at(id).storeRow() < 0 || !table_.restored(id))
    return {StatusCode::kNotFound, "no stored session named '" + name_or_id + "' in " + view_.storeName() +
                                       " (list_sessions shows the stored ones as UNLOADED)"};
  Session& s = table_.at(id);
  if (!s.unloaded) {
    out->id = id;
    return {StatusCode::kAlreadyExists, "session " + std::to_string(id) + " ('" + s.name() + "') is already loaded"};
  }
  ReloadedSession r;
  try {
    if (read != ReloadRead::kNothing)
      r.keyframes =
          table_.store()->keyframes(s.storeRow(), read == ReloadRead::kFeatures ? SessionStore::KeyframeColumns::kAll
                                                                                : SessionStore::KeyframeColumns::kHash);
  } catch (const std::exception& e) {
    say("reload_session '" + name_or_id + "': reading " + table_.options().store_path + " failed: " + e.what());
    // The reply names the file only: the store's errors carry its full path.
    std::string why = e.what();
    const std::string& path = table_.options().store_path;
    const std::string name = view_.storeName();
    for (std::size_t at = why.find(path); at != std::string::npos; at = why.find(path, at + name.size()))
      why.replace(at, path.size(), name);
    return {StatusCode::kDataLoss, "reading " + view_.storeName() + ": " + why};
  }
  r.id = id;
  r.camera = s.camera;
  s.unloaded = false;
  // Older stores kept a 0x0 camera for some sessions with keyframes: their features cannot be put
  // in metres, so no loop to them verifies (the loop detector refuses such keyframes).
  if (s.camera.unknown() && !s.stamps.empty())
    say("session " + std::to_string(id) + " '" + s.name() + "' has no stored camera (0x0, written by an older " +
        "version): no loop to its " + std::to_string(s.stamps.size()) + " keyframes can be verified");
  *out = std::move(r);
  return Status::Ok();
}

Status SessionManager::unload(const std::string& name_or_id, int* id_out) {
  if (id_out) *id_out = -1;
  if (!table_.store())
    return {StatusCode::kFailedPrecondition, "no session store: nothing was reloaded, nothing to unload"};
  const int id = table_.findSession(name_or_id);
  if (id < 0)
    return {StatusCode::kNotFound, "no session named or numbered '" + name_or_id + "' (list_sessions shows them)"};
  if (id_out) *id_out = id;
  Session& s = table_.at(id);
  if (!table_.restored(id))
    return {StatusCode::kFailedPrecondition,
            "session " + std::to_string(id) + " ('" + s.name() +
                "') was recorded in this run: only sessions restored from the store can be unloaded "
                "(reload_session brings them back)"};
  if (s.unloaded)
    return {StatusCode::kFailedPrecondition, "session " + std::to_string(id) + " ('" + s.name() + "') is not loaded"};
  s.unloaded = true;
  say("unload_session '" + name_or_id + "': session " + std::to_string(id) + " UNLOADED (its " +
      std::to_string(s.stamps.size()) + " keyframes stay in the store and in map " + std::to_string(view_.mapOf(id)) +
      ")");
  return Status::Ok();
}

Status SessionManager::deleteSession(const std::string& name_or_id, bool confirm, int* id_out) {
  if (id_out) *id_out = -1;
  if (!table_.store()) return {StatusCode::kFailedPrecondition, "no session store: nothing to delete from"};
  if (const Status mode = view_.storedMapsMayChange("delete_session"); !mode.ok()) return mode;
  const int id = table_.findSession(name_or_id);
  if (id < 0)
    return {StatusCode::kNotFound, "no session named or numbered '" + name_or_id + "' (list_sessions shows them)"};
  if (id_out) *id_out = id;
  const Session& s = table_.at(id);
  const std::string what = "session " + std::to_string(id) + " ('" + s.name() + "')";
  const MultiSessionBackend& backend = table_.backend();
  if (id == table_.active() || backend.session(s.backend()).recording)
    return {StatusCode::kFailedPrecondition, what + " is recording: finish_session first"};
  const std::vector<int> chain = backend.chain(backend.mapOf(s.backend()));
  if (chain.size() != 1)
    return {StatusCode::kFailedPrecondition, what + " shares map " + std::to_string(view_.mapOf(id)) + " with " +
                                                 std::to_string(chain.size() - 1) +
                                                 " other sessions: split_session it off first"};
  const std::string lost = std::to_string(s.stamps.size()) + " keyframes, " + std::to_string(s.loops()) + " loops";
  if (!confirm)
    return {StatusCode::kFailedPrecondition,
            "delete_session removes " + what + " (" + lost + ") from the store for good: call again with confirm true"};
  recordMapChanges();  // none is pending; were one, it would go in before the deletion
  const std::string name = s.name();
  const HistoryEntry entry = nextEntry("delete", std::to_string(id), "",
                                       "session " + std::to_string(id) + " '" + name + "' deleted (" + lost + ")",
                                       table_.options().requester.c_str());
  const bool in_store = s.storeRow() >= 0;
  if (in_store) {
    try {
      table_.store()->deleteSessions({s.storeRow()}, &entry);  // one transaction with its history entry: all or nothing
    } catch (const std::exception& e) {
      say("delete_session '" + name_or_id + "': " + e.what());
      return {StatusCode::kDataLoss, "the store could not be changed, nothing deleted: " + std::string(e.what())};
    }
  }
  table_.remove(id);  // `s` is gone from here on; the back-end's indexes after it move down one
  if (!in_store) storeWrite("writing the history", [&] { table_.store()->addHistory(entry); });  // never stored itself
  table_.appendHistory(entry);
  say("delete_session '" + name_or_id + "': session " + std::to_string(id) + " '" + name + "' deleted (" + lost +
      ") from " + view_.storeName() + " and from memory");
  return Status::Ok();
}

}  // namespace core
}  // namespace uw_multislam
