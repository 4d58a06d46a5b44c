# What differs between the platforms the core builds on (Debian 12; Debian 11 and Ubuntu 20.04 with
# ROS Noetic; JetPack 5 on Ubuntu 20.04 arm64), shared by the package's CMakeLists.txt and
# scripts/arm64/CMakeLists.txt. Include it after find_package(OpenCV). It sets
#   UWMS_PLATFORM_DEFINITIONS  compile definitions of the core (which SIFT implementations it has)
#   UWMS_PLATFORM_LIBRARIES    what the core links for them (OpenCV's xfeatures2d, VLFeat, stdc++fs)
#   UWMS_OPENCV_SIFT           features2d | xfeatures2d | none: where OpenCV's SIFT comes from
#   UWMS_HAVE_VLFEAT           whether VLFeat's SIFT is built in
list(APPEND CMAKE_MODULE_PATH ${CMAKE_CURRENT_LIST_DIR})
set(UWMS_PLATFORM_DEFINITIONS "")
set(UWMS_PLATFORM_LIBRARIES "")

# SIFT (odometry.features.sift_backend): OpenCV's cv::SIFT in features2d from 4.4 on (the patent
# expired in 2020); before, cv::xfeatures2d::SIFT of opencv_contrib (Ubuntu 20.04's 4.2 builds it
# without OPENCV_ENABLE_NONFREE, so it may throw when created: checked at run time); else VLFeat, the
# SIFT of the multi-session paper's own code (libvlfeat-dev, amd64 only in Debian and Ubuntu).
# -DUWMS_FORCE_SIFT_BACKEND=vlfeat builds as if OpenCV had no SIFT (the fallback alone);
# =opencv leaves VLFeat out.
set(UWMS_FORCE_SIFT_BACKEND "" CACHE STRING "Build only this SIFT backend: opencv or vlfeat (empty: every one found)")
set_property(CACHE UWMS_FORCE_SIFT_BACKEND PROPERTY STRINGS "" opencv vlfeat)
if(NOT UWMS_FORCE_SIFT_BACKEND MATCHES "^(|opencv|vlfeat)$")
  message(FATAL_ERROR "UWMS_FORCE_SIFT_BACKEND=${UWMS_FORCE_SIFT_BACKEND}: give opencv, vlfeat or nothing")
endif()
if(UWMS_FORCE_SIFT_BACKEND STREQUAL "vlfeat")
  set(UWMS_OPENCV_SIFT none)
elseif(OpenCV_VERSION VERSION_GREATER_EQUAL 4.4)
  set(UWMS_OPENCV_SIFT features2d)
  list(APPEND UWMS_PLATFORM_DEFINITIONS UWMS_OPENCV_SIFT_FEATURES2D)
elseif(TARGET opencv_xfeatures2d)
  set(UWMS_OPENCV_SIFT xfeatures2d)
  list(APPEND UWMS_PLATFORM_DEFINITIONS UWMS_OPENCV_SIFT_XFEATURES2D)
  list(APPEND UWMS_PLATFORM_LIBRARIES opencv_xfeatures2d)
else()
  set(UWMS_OPENCV_SIFT none)
endif()
set(UWMS_HAVE_VLFEAT OFF)
if(NOT UWMS_FORCE_SIFT_BACKEND STREQUAL "opencv")
  find_package(VLFeat)
  if(VLFeat_FOUND)
    set(UWMS_HAVE_VLFEAT ON)
    list(APPEND UWMS_PLATFORM_DEFINITIONS UWMS_HAVE_VLFEAT)
    list(APPEND UWMS_PLATFORM_LIBRARIES VLFeat::vl)
  endif()
endif()
if(UWMS_OPENCV_SIFT STREQUAL "none" AND NOT UWMS_HAVE_VLFEAT)
  message(FATAL_ERROR "No SIFT: OpenCV ${OpenCV_VERSION} (OpenCV_DIR=${OpenCV_DIR}) has none (cv::SIFT is in features2d "
    "from 4.4 on, cv::xfeatures2d::SIFT needs opencv_contrib; -DUWMS_FORCE_SIFT_BACKEND=${UWMS_FORCE_SIFT_BACKEND}), and VLFeat was not found. "
    "Install libvlfeat-dev with SIFT (Debian 12's 0.9.21+full; the '+dfsg' packages of Debian 11 and Ubuntu leave it "
    "out), or build VLFeat from its source and pass -DVLFeat_ROOT=<prefix of include/vl/sift.h and lib/libvl.so>.")
endif()
if(UWMS_FORCE_SIFT_BACKEND STREQUAL "opencv" AND UWMS_OPENCV_SIFT STREQUAL "none")
  message(FATAL_ERROR "UWMS_FORCE_SIFT_BACKEND=opencv, but OpenCV ${OpenCV_VERSION} has no SIFT (features2d from 4.4 "
    "on, or opencv_contrib's xfeatures2d)")
endif()
message(STATUS "uw_multislam SIFT: OpenCV ${OpenCV_VERSION}'s from ${UWMS_OPENCV_SIFT}, VLFeat ${UWMS_HAVE_VLFEAT} "
  "${VLFeat_VERSION} (UWMS_FORCE_SIFT_BACKEND='${UWMS_FORCE_SIFT_BACKEND}')")

# std::filesystem: GCC before 9.1 keeps it in libstdc++fs (9.1 and later, and clang's libc++ 9, in
# the main library).
if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU" AND CMAKE_CXX_COMPILER_VERSION VERSION_LESS 9.1)
  list(APPEND UWMS_PLATFORM_LIBRARIES stdc++fs)
endif()
