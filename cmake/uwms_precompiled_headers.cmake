# Precompiled headers: the third-party headers that nearly every unit of a target parses (the
# standard library, Eigen, OpenCV, gtest, roscpp and the message headers) are parsed once per
# target instead of once per unit (doc/benchmarks/ci.md has what it saves on CI's from-scratch build).
#
# UWMS_PCH: ON, OFF or AUTO (the default): ON unless the compiler runs through ccache. ccache caches
# no unit compiled with a precompiled header unless its sloppiness allows it (pch_defines,
# time_macros), and a warm cache saves more than a precompiled header does; a build without a cache
# (CI's clean clone) has nothing to lose.
#
# A precompiled header is only used where the compiler accepts it: GCC rejects one made with other
# macros (-D, and __OPTIMIZE__ from -O), another -fpic or -fpie, so a target shares another's
# (REUSE_FROM) only when both are compiled alike, and the gtests, compiled at -O0, have their own.
# CMake adds -Winvalid-pch, so with -Werror a rejected header fails the build instead of being
# ignored in silence. Every unit still includes what it uses: builds with UWMS_PCH=OFF compile
# without them.
set(UWMS_PCH AUTO CACHE STRING "Precompiled headers for the heavy third-party headers: ON, OFF or AUTO (ON unless built through ccache)")
set_property(CACHE UWMS_PCH PROPERTY STRINGS AUTO ON OFF)
if(UWMS_PCH STREQUAL "AUTO")
  get_filename_component(_uwms_compiler_real "${CMAKE_CXX_COMPILER}" REALPATH)
  if("${CMAKE_CXX_COMPILER_LAUNCHER}" MATCHES "ccache" OR _uwms_compiler_real MATCHES "ccache")
    set(UWMS_USE_PCH OFF)
  else()
    set(UWMS_USE_PCH ON)
  endif()
elseif(UWMS_PCH)
  set(UWMS_USE_PCH ON)
else()
  set(UWMS_USE_PCH OFF)
endif()
message(STATUS "uw_multislam: precompiled headers ${UWMS_USE_PCH} (UWMS_PCH=${UWMS_PCH})")

# What the core's units include most (and the standard library's heavy templates).
set(UWMS_PCH_CORE_HEADERS <algorithm> <functional> <map> <memory> <mutex> <optional> <string> <vector>
  <Eigen/Core> <Eigen/Dense> <opencv2/core.hpp> <opencv2/imgproc.hpp>)
# The ROS libraries': roscpp, the message headers they convert, tf2 and cv_bridge, on top of the core's.
set(UWMS_PCH_ROS_HEADERS ${UWMS_PCH_CORE_HEADERS} <ros/ros.h> <std_msgs/Header.h> <sensor_msgs/Image.h>
  <sensor_msgs/CameraInfo.h> <nav_msgs/Odometry.h> <geometry_msgs/PoseWithCovarianceStamped.h> <tf2_ros/buffer.h>
  <cv_bridge/cv_bridge.h>)

# uwms_precompile_headers(TARGET target HEADERS h...): the target's own precompiled header.
# uwms_precompile_headers(TARGET target REUSE_FROM other): the other target's (compiled alike).
function(uwms_precompile_headers)
  cmake_parse_arguments(ARG "" "TARGET;REUSE_FROM" "HEADERS" ${ARGN})
  if(NOT UWMS_USE_PCH OR NOT TARGET ${ARG_TARGET})
    return()
  endif()
  if(ARG_REUSE_FROM)
    target_precompile_headers(${ARG_TARGET} REUSE_FROM ${ARG_REUSE_FROM})
  else()
    target_precompile_headers(${ARG_TARGET} PRIVATE ${ARG_HEADERS})
  endif()
endfunction()
