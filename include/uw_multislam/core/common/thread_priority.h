// A worker thread's CPU share against the others of its process: on Linux each thread has its own
// nice value (setpriority(PRIO_PROCESS, tid), man 7 sched), so the work that is not latency bound
// (loop detection, the back-end's optimisation) can yield the cores to the odometry's frames when
// both want them, without a real-time policy or a privilege (raising a priority needs
// CAP_SYS_NICE; lowering one does not).
#pragma once

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <string>

namespace uw_multislam {
namespace core {

/// Sets the calling thread's nice value to `nice` (0..19; 0: left as it is). False, with the
/// reason in `why`, when it is out of range or refused (the thread then runs at its former one).
inline bool setThisThreadNice(int nice, std::string* why) {
  if (nice == 0) return true;
  if (nice < 0 || nice > 19) {
    if (why) *why = "nice " + std::to_string(nice) + " is outside [0, 19] (only lowering a priority is supported)";
    return false;
  }
#ifdef __linux__
  const auto tid = static_cast<id_t>(::syscall(SYS_gettid));
  if (::setpriority(PRIO_PROCESS, tid, nice) == 0) return true;
  if (why) *why = std::string("setpriority: ") + std::strerror(errno);
  return false;
#else
  if (why) *why = "per-thread nice values are Linux only";
  return false;
#endif
}

/// The calling thread's nice value (Linux; 0 elsewhere).
inline int thisThreadNice() {
#ifdef __linux__
  errno = 0;
  return ::getpriority(PRIO_PROCESS, static_cast<id_t>(::syscall(SYS_gettid)));
#else
  return 0;
#endif
}

}  // namespace core
}  // namespace uw_multislam
