#include "uw_multislam/core/store/store_merge.h"

#include <sqlite3.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <set>
#include <stdexcept>

#include "uw_multislam/core/common/file_identity.h"
#include "uw_multislam/core/loops/haloc.h"
#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/core/session/stored_loops.h"
#include "uw_multislam/core/store/map_persistence.h"
#include "uw_multislam/core/store/session_store.h"

namespace uw_multislam {
namespace core {

namespace {

namespace fs = std::filesystem;

// The temporary output and what SQLite puts beside it; removed unless published. The store is
// created exclusively (StoreAccess::kCreateNew): a file already at the name, a link planted
// there, is never opened nor removed; only the file made here is.
class TemporaryStore {
 public:
  explicit TemporaryStore(const std::string& out) {
    for (int attempt = 0; attempt < 100; ++attempt) {
      const std::string candidate =
          out + ".partial-" + std::to_string(getpid()) + (attempt ? "-" + std::to_string(attempt) : "");
      struct stat st {};
      if (::lstat(candidate.c_str(), &st) == 0 || errno != ENOENT) continue;  // taken: never ours to use
      path_ = candidate;
      return;
    }
    throw StoreError(out + ": no free name for the temporary store beside it");
  }
  ~TemporaryStore() {
    if (!made_) return;
    struct stat st {};
    if (::lstat(path_.c_str(), &st) == 0 && FileId{st.st_dev, st.st_ino} == id_) ::unlink(path_.c_str());
    for (const char* suffix : {"-wal", "-shm"})
      if (::lstat((path_ + suffix).c_str(), &st) == 0 && S_ISREG(st.st_mode)) ::unlink((path_ + suffix).c_str());
  }
  TemporaryStore(const TemporaryStore&) = delete;
  TemporaryStore& operator=(const TemporaryStore&) = delete;
  const std::string& path() const { return path_; }
  /// Called once the store is created: its identity, for the removal.
  void made() { made_ = fileIdOf(path_, &id_); }

 private:
  std::string path_;
  FileId id_;
  bool made_ = false;
};

std::string settingsText(const HashSettings& h) {
  return std::string("hash_mode ") + hashModeName(h.mode) + ", projection_seed " + std::to_string(h.seed) +
         ", n = " + std::to_string(h.num_features) + ", " + featureTypeName(h.features) + " features";
}

}  // namespace

MergeReport mergeStores(const std::string& out, const std::vector<MergeInput>& inputs, SlamConfig config,
                        bool search_loops, const std::function<void(const std::string&)>& log) {
  auto say = [&](const std::string& line) {
    if (log) log(line);
  };
  MergeReport report;
  if (inputs.empty()) throw std::invalid_argument("merge_stores: no input store");
  std::error_code ec;
  if (fs::exists(fs::symlink_status(out, ec)))
    throw std::invalid_argument(out + ": exists; merge_stores writes a new store and never overwrites one");
  const fs::path parent = fs::path(out).parent_path();
  if (!parent.empty() && !fs::is_directory(parent, ec))
    throw std::invalid_argument(out + ": the directory " + parent.string() + " does not exist");

  // --- Inputs: read-only, distinct, comparable hashes, nothing recording ----------------------
  std::vector<std::unique_ptr<SessionStore>> in;
  std::map<FileId, std::string>
      seen;  // by identity: a hard link, a bind mount or a symbolic link to one store is that store
  HashSettings settings;
  for (std::size_t i = 0; i < inputs.size(); ++i) {
    const std::string& path = inputs[i].path;
    FileId id;
    if (!fileIdOf(path, &id)) throw std::invalid_argument(path + ": no such store");
    const auto [first, fresh] = seen.emplace(id, path);
    if (!fresh)
      throw std::invalid_argument(path + ": given twice: it is the same file as " + first->second +
                                  " (the same path, or a hard or symbolic link to it); each store once");
    in.push_back(std::make_unique<SessionStore>(path, StoreAccess::kReadOnly));
    HashSettings h;
    if (!in.back()->hashSettings(&h))
      throw std::invalid_argument(path + ": has no hash settings (no session was ever stored in it)");
    // The stored projection vectors, read back and checked against the store's own settings: a
    // damaged text was blamed below on the other input's "other projection vectors".
    try {
      const HalocProjections p = HalocProjections::fromText(h.projections);
      if (p.n() != h.num_features || p.seed() != h.seed)
        throw std::invalid_argument("vectors for n = " + std::to_string(p.n()) + ", seed " + std::to_string(p.seed()) +
                                    ", settings n = " + std::to_string(h.num_features) + ", seed " +
                                    std::to_string(h.seed));
    } catch (const std::invalid_argument& e) {
      throw StoreError("session store " + path + ": its meta table is damaged (projections: " + e.what() + ")");
    }
    if (i == 0) {
      settings = h;
    } else if (h.mode != settings.mode || h.seed != settings.seed || h.num_features != settings.num_features ||
               h.projections != settings.projections || h.features != settings.features) {
      throw std::invalid_argument(path + ": its hashes were made with " + settingsText(h) + ", " + inputs[0].path +
                                  "'s with " + settingsText(settings) +
                                  (h.projections != settings.projections && h.mode == settings.mode &&
                                           h.seed == settings.seed && h.num_features == settings.num_features
                                       ? " but other projection vectors"
                                       : "") +
                                  ": hashes of the two could not be compared, so no loop could be found between them");
    }
    for (const StoredSession& s : in.back()->sessions())
      if (s.state == StoredSessionState::kRecording && s.keyframes > 0)
        throw std::invalid_argument(
            path + ": session " + std::to_string(s.id) + " '" + s.name +
            "' is still recording (an interrupted run): finish or discard it first (offline_slam --db " + path +
            " --session ITS_FOLDER --interrupted finish|discard)");
    {  // The checks every reader of a store applies (a damaged row refused by name), before
       // anything is copied: the copy reads rows itself and took a dangling loop without a word.
      MultiSessionBackend scratch{BackendOptions{}};
      restoreStore(*in.back(), &scratch, nullptr, nullptr);
    }
  }
  config.loops.global.hash_mode = settings.mode;
  config.loops.global.projection_seed = settings.seed;
  config.odometry.features.num_features = settings.num_features;
  config.odometry.features.type = settings.features;
  report.inputs = static_cast<int>(inputs.size());

  // --- Copy into a temporary file beside OUT ----------------------------------------------------
  TemporaryStore tmp(out);
  std::vector<int> input_of;  // the input of each merged session, by the id the manager gives it (copy order)
  {
    SessionStore dst(tmp.path(), StoreAccess::kCreateNew);
    tmp.made();
    // The temporary file is renamed only when complete, so a crash loses nothing durable:
    // per-keyframe fsyncs (synchronous=FULL, one transaction per keyframe) would make a 100-dive
    // merge take hours. Synced once at the end (checkpoint), and by the manager's own writes.
    sqlite3_exec(dst.handle(), "PRAGMA synchronous=OFF", nullptr, nullptr, nullptr);
    dst.checkHashSettings(settings);
    std::set<std::string> names;
    std::vector<StoredMap> maps;
    std::vector<StoredLoop> states;
    std::vector<std::pair<std::int64_t, std::int64_t>> pairs;
    for (std::size_t i = 0; i < in.size(); ++i) {
      const SessionStore& src = *in[i];
      const std::string vehicle =
          inputs[i].vehicle.empty() ? fs::path(inputs[i].path).stem().string() : inputs[i].vehicle;
      std::map<std::int64_t, std::int64_t> session_of;  // source store id -> merged store id
      for (const StoredSession& s : src.sessions()) {
        if (s.keyframes == 0) {  // created, then nothing (the back-end never restores it either)
          ++report.skipped_empty_sessions;
          continue;
        }
        std::string name = s.name;
        if (names.count(name)) {
          name = s.name + "@" + vehicle;
          for (int k = 2; names.count(name); ++k) name = s.name + "@" + vehicle + "#" + std::to_string(k);
          ++report.renamed_sessions;
        }
        names.insert(name);
        const std::vector<StoredKeyframe> keyframes = src.keyframes(s.id, SessionStore::KeyframeColumns::kAll);
        const std::vector<UncertainPose2> odometry = src.odometry(s.id);
        const std::vector<MotionSource> sources = src.motionSources(s.id);
        if (odometry.size() + 1 != keyframes.size() || sources.size() != odometry.size())
          throw StoreError("session store " + inputs[i].path + ": session " + std::to_string(s.id) + " has " +
                           std::to_string(keyframes.size()) + " keyframes and " + std::to_string(odometry.size()) +
                           " motions");
        const std::int64_t id = dst.addSession(name, s.camera, s.start_stamp_s);
        session_of[s.id] = id;
        for (std::size_t k = 0; k < keyframes.size(); ++k) {
          StoredKeyframe kf = keyframes[k];
          if (kf.keyframe != static_cast<int>(k))
            throw StoreError("session store " + inputs[i].path + ": session " + std::to_string(s.id) +
                             " misses keyframe " + std::to_string(k));
          kf.session = id;
          kf.motion_source = k > 0 ? sources[k - 1] : MotionSource::kVisual;
          dst.addKeyframe(kf, k > 0 ? &odometry[k - 1] : nullptr, nullptr);
        }
        dst.endSession(id, s.end_stamp_s);
        dst.addProvenance(
            {id, inputs[i].path, s.id, s.name, vehicle, inputs[i].dive.empty() ? s.name : inputs[i].dive});
        report.keyframes += static_cast<int>(keyframes.size());
        ++report.sessions;
        input_of.push_back(static_cast<int>(i));
      }
      std::vector<StoredLoop> loops, sources;
      for (const StoredLoop& l : src.loops()) {
        if (!session_of.count(l.session_a) || !session_of.count(l.session_b)) continue;
        StoredLoop c = l;
        c.session_a = session_of[l.session_a];
        c.session_b = session_of[l.session_b];
        loops.push_back(c);
        sources.push_back(l);
      }
      dst.addLoops(&loops);  // sets their new ids
      std::map<std::int64_t, std::int64_t> loop_of;
      for (std::size_t k = 0; k < loops.size(); ++k) {
        loop_of[sources[k].id] = loops[k].id;
        states.push_back(loops[k]);  // summarised / applied / refused as in the source
      }
      report.copied_loops += static_cast<int>(loops.size());
      for (const StoredMap& m : src.maps()) {
        StoredMap c = m;
        bool complete = true;
        for (std::int64_t& s : c.chain) {
          complete = complete && session_of.count(s) > 0;
          if (complete) s = session_of[s];
        }
        for (StoredPrior& p : c.priors) p.session = session_of.count(p.session) ? session_of[p.session] : -1;
        if (!complete) continue;  // names a session without keyframes: restore skips it too
        for (StoredLink& l : c.links) {
          std::vector<std::int64_t> ids;
          for (std::int64_t id : l.loops)
            if (loop_of.count(id)) ids.push_back(loop_of[id]);
          l.loops = ids;
        }
        maps.push_back(std::move(c));
      }
      for (const auto& [a, b] : src.splitPairs())
        if (session_of.count(a) && session_of.count(b)) pairs.emplace_back(session_of[a], session_of[b]);
      say(inputs[i].path + ": " + std::to_string(session_of.size()) + " sessions, " + std::to_string(loops.size()) +
          " loops copied (vehicle '" + vehicle + "')");
    }
    dst.saveMaps(maps, states, pairs);
    sqlite3_exec(dst.handle(), "PRAGMA synchronous=FULL", nullptr, nullptr, nullptr);
    dst.checkpoint();
  }
  in.clear();

  // --- Global loops between the inputs, joins by the manager's policy ---------------------------
  {
    SessionManager manager(sessionManagerOptions(config, tmp.path()), {}, say);
    if (manager.view().hasher().projections().toText() != settings.projections)
      throw std::invalid_argument("the inputs' projection vectors are not the ones this build makes from " +
                                  settingsText(settings) + ": no loop could be found between them");
    if (static_cast<int>(manager.view().sessionIds().size()) != report.sessions)
      throw StoreError("merge_stores: the merged store restores " + std::to_string(manager.view().sessionIds().size()) +
                       " sessions, " + std::to_string(report.sessions) + " were copied");
    const int joins_before = manager.view().backendStats().joins;
    if (search_loops && inputs.size() > 1) {
      std::vector<std::vector<int>> groups(inputs.size());  // the merged sessions of each input
      for (std::size_t s = 0; s < input_of.size(); ++s) groups[input_of[s]].push_back(static_cast<int>(s));
      const StoredLoopSearch found = searchStoredLoops(&manager, config, groups, say);
      report.queries = found.queries;
      report.candidates = found.candidates;
      report.loops_found = found.found;
      report.loops_accepted = found.accepted;
      report.loops_refused = found.refused;
    }
    manager.flush();  // optimises what the new loops made due, saves the maps
    if (manager.view().stats().store_failures > 0)
      throw StoreError("merge_stores: " + std::to_string(manager.view().stats().store_failures) +
                       " writes to the merged store failed (see the log)");
    report.joins = manager.view().backendStats().joins - joins_before;
    report.maps = static_cast<int>(manager.view().mapIds().size());
  }

  // --- Publish: a hard link never replaces an OUT that appeared meanwhile -----------------------
  // The manager's connection was the last: SQLite checkpointed its WAL into the file and removed it.
  if (fs::exists(tmp.path() + "-wal", ec) && fs::file_size(tmp.path() + "-wal", ec) > 0)
    throw StoreError(tmp.path() + ": its write-ahead log was not checkpointed; nothing was written to " + out);
  if (::link(tmp.path().c_str(), out.c_str()) != 0)
    throw StoreError(out + ": cannot create the merged store: " + std::strerror(errno));
  return report;
}

}  // namespace core
}  // namespace uw_multislam
