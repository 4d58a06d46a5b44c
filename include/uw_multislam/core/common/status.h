// The outcome of a request to the core (join, split, start, reload, ...). The codes are those of
// msg/Status.msg (cartographer_ros' StatusCode, gRPC's numbering), so the ROS layer copies the
// value and never translates. A request that fails changes nothing.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace uw_multislam {
namespace core {

enum class StatusCode : std::uint8_t {
  kOk = 0,
  kInvalidArgument = 3,     // a bad value in the request (the message names it)
  kNotFound = 5,            // no session / map with that id or name
  kAlreadyExists = 6,       // e.g. a session name already taken, a session already loaded
  kResourceExhausted = 8,   // a limit is reached (e.g. too many empty sessions, no session id left)
  kFailedPrecondition = 9,  // a valid request the current state does not allow
  kInternal = 13,
  kUnavailable = 14,  // busy now (e.g. another export running): try again
  kDataLoss = 15,     // the session store could not be read
};

struct Status {
  StatusCode code = StatusCode::kOk;
  std::string message;  // a sentence a person can act on; empty when OK
  bool ok() const { return code == StatusCode::kOk; }
  static Status Ok(std::string message = "") { return {StatusCode::kOk, std::move(message)}; }
};

const char* statusCodeName(StatusCode c);

/// `s` with every occurrence of each path of `roles` ({path, role}, e.g. {"/data/s.db", "the
/// store"}) replaced by its role, longer paths first (a folder inside a named one keeps its own
/// name relative to the role). Services answer any caller: they name files by role, and the node
/// logs the full message. Empty paths are ignored.
Status withRoles(Status s, std::vector<std::pair<std::string, std::string>> roles);

/// The roles for withRoles of the session store's and the export root's paths ("the store", "the
/// export root"; an empty path: none): each path as given, resolved and absolute (a relative path,
/// or one through a symlink, appears absolute in the core's messages), with and without the words
/// and quotes the core puts around it ("session store PATH", "export root 'PATH'").
std::vector<std::pair<std::string, std::string>> pathRoles(const std::string& store_path,
                                                           const std::string& export_root);

}  // namespace core
}  // namespace uw_multislam
