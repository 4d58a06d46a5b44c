// What the session manager's files share (private to src/core/session): the checks and texts
// of ids that several requests use.
#pragma once

#include <stdexcept>
#include <string>

#include "uw_multislam/core/session/session_queries.h"

namespace uw_multislam {
namespace core {
namespace session_detail {

inline BackendOptions checked(const SessionManagerOptions& o) {
  const std::string bad = o.validate();
  if (!bad.empty()) throw std::invalid_argument("session manager: " + bad);
  return o.backend;
}

inline Status notFound(int session) {
  return {StatusCode::kNotFound, "no session " + std::to_string(session) + " (call list_sessions for the ids)"};
}

inline bool validSessionId(int id) { return id >= 0 && id <= kMaxSessionId; }

inline Status badSessionId(const std::string& what, int id) {
  return {StatusCode::kInvalidArgument, what + " names session " + std::to_string(id) + ", outside the ids [0, " +
                                            std::to_string(kMaxSessionId) + "]"};
}

/// A loop as the audit trail names it: "a:ka>b:kb" in session ids.
inline std::string loopText(const Loop& l) {
  return std::to_string(l.session_a) + ":" + std::to_string(l.keyframe_a) + ">" + std::to_string(l.session_b) + ":" +
         std::to_string(l.keyframe_b);
}

}  // namespace session_detail
}  // namespace core
}  // namespace uw_multislam
