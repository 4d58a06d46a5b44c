#include "uw_multislam/core/common/status.h"

#include <algorithm>
#include <filesystem>

namespace uw_multislam {
namespace core {

const char* statusCodeName(StatusCode c) {
  switch (c) {
    case StatusCode::kOk:
      return "OK";
    case StatusCode::kInvalidArgument:
      return "INVALID_ARGUMENT";
    case StatusCode::kNotFound:
      return "NOT_FOUND";
    case StatusCode::kAlreadyExists:
      return "ALREADY_EXISTS";
    case StatusCode::kResourceExhausted:
      return "RESOURCE_EXHAUSTED";
    case StatusCode::kFailedPrecondition:
      return "FAILED_PRECONDITION";
    case StatusCode::kInternal:
      return "INTERNAL";
    case StatusCode::kUnavailable:
      return "UNAVAILABLE";
    case StatusCode::kDataLoss:
      return "DATA_LOSS";
  }
  return "UNKNOWN";
}

Status withRoles(Status s, std::vector<std::pair<std::string, std::string>> roles) {
  std::stable_sort(roles.begin(), roles.end(),
                   [](const auto& a, const auto& b) { return a.first.size() > b.first.size(); });
  for (const auto& [path, role] : roles) {
    if (path.empty()) continue;
    for (std::size_t at = s.message.find(path); at != std::string::npos; at = s.message.find(path, at + role.size()))
      s.message.replace(at, path.size(), role);
  }
  return s;
}

std::vector<std::pair<std::string, std::string>> pathRoles(const std::string& store_path,
                                                           const std::string& export_root) {
  std::vector<std::pair<std::string, std::string>> roles;
  const std::pair<std::string, std::string> words[] = {{"session store", "the store"},
                                                       {"export root", "the export root"}};
  const std::string* paths[] = {&store_path, &export_root};
  for (int i = 0; i < 2; ++i) {
    const std::string& path = *paths[i];
    const auto& [word, role] = words[i];
    if (path.empty()) continue;
    std::error_code ec;
    const std::string resolved = std::filesystem::weakly_canonical(path, ec).string();
    const std::string absolute = std::filesystem::absolute(path, ec).lexically_normal().string();
    for (const std::string& p : {path, resolved, absolute}) {
      roles.push_back({word + " '" + p + "'", role});
      roles.push_back({word + " " + p, role});
      roles.push_back({"'" + p + "'", role});
      roles.push_back({p, role});
    }
  }
  return roles;
}

}  // namespace core
}  // namespace uw_multislam
