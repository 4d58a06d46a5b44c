# FindVLFeat: VLFeat's C library (Debian and Ubuntu: libvlfeat-dev, headers vl/*.h and libvl.so; no
# CMake config or pkg-config file ships with it).
#
# Defines VLFeat_FOUND, VLFeat_INCLUDE_DIR, VLFeat_LIBRARY, VLFeat_VERSION (from vl/generic.h) and the
# imported target VLFeat::vl. Hints: -DVLFeat_ROOT=<prefix> (CMake's <Package>_ROOT), or the cache
# variables VLFeat_INCLUDE_DIR and VLFeat_LIBRARY.
find_path(VLFeat_INCLUDE_DIR NAMES vl/sift.h)
# Debian 11's libvlfeat-dev (0.9.21+dfsg0, and Ubuntu's of the same version) leaves SIFT out: a VLFeat
# without vl/sift.h is not found, and says so.
find_path(_vlfeat_generic NAMES vl/generic.h)
if(_vlfeat_generic AND NOT VLFeat_INCLUDE_DIR AND NOT VLFeat_FIND_QUIETLY)
  message(STATUS "VLFeat in ${_vlfeat_generic} has no SIFT (vl/sift.h): a '+dfsg' package strips it; Debian 12's "
    "libvlfeat-dev (0.9.21+full) or VLFeat built from its source (make) has it (-DVLFeat_ROOT=<its prefix>)")
endif()
unset(_vlfeat_generic CACHE)
find_library(VLFeat_LIBRARY NAMES vl)
if(VLFeat_INCLUDE_DIR AND EXISTS "${VLFeat_INCLUDE_DIR}/vl/generic.h")
  file(STRINGS "${VLFeat_INCLUDE_DIR}/vl/generic.h" _vlfeat_version REGEX "^#define VL_VERSION_STRING ")
  string(REGEX REPLACE ".*\"([0-9.]+)\".*" "\\1" VLFeat_VERSION "${_vlfeat_version}")
  unset(_vlfeat_version)
endif()
include(FindPackageHandleStandardArgs)
find_package_handle_standard_args(VLFeat REQUIRED_VARS VLFeat_LIBRARY VLFeat_INCLUDE_DIR VERSION_VAR VLFeat_VERSION)
mark_as_advanced(VLFeat_INCLUDE_DIR VLFeat_LIBRARY)
if(VLFeat_FOUND AND NOT TARGET VLFeat::vl)
  add_library(VLFeat::vl UNKNOWN IMPORTED)
  set_target_properties(VLFeat::vl PROPERTIES IMPORTED_LOCATION "${VLFeat_LIBRARY}"
    INTERFACE_INCLUDE_DIRECTORIES "${VLFeat_INCLUDE_DIR}")
endif()
