# Unity builds: the core's objects and test_core compiled as a few units that each include several
# source files, so that what the precompiled header does not hold (the repository's own headers,
# and at test_core's -O0 the inline functions and templates every unit instantiates and emits
# again) is parsed and compiled once per batch instead of once per file (doc/benchmarks/ci.md has
# what it saves on CI's from-scratch build).
#
# UWMS_UNITY: ON, OFF or AUTO (the default): ON unless the compiler runs through ccache, as for the
# precompiled headers: a cached build recompiles single files, and a batch would be recompiled
# whole for one changed file. CMake 3.16 has unity builds; test_core's groups need 3.18 (bullseye's).
#
# Files of one batch share a unit, so their file-local helpers (anonymous namespaces, static
# functions) must not clash: the core's do not; test_core's do (several test files define their
# own options(), diag(), keyframe(), kAltitude...), so its files go in explicit groups in which no
# two define the same helper (CMakeLists.txt). A clash fails the build (a redefinition or an
# ambiguous call), never silently. A file in no group is compiled alone.
set(UWMS_UNITY AUTO CACHE STRING "Unity builds of the core's objects and test_core: ON, OFF or AUTO (ON unless built through ccache)")
set_property(CACHE UWMS_UNITY PROPERTY STRINGS AUTO ON OFF)
if(UWMS_UNITY STREQUAL "AUTO")
  get_filename_component(_uwms_compiler_real "${CMAKE_CXX_COMPILER}" REALPATH)
  if("${CMAKE_CXX_COMPILER_LAUNCHER}" MATCHES "ccache" OR _uwms_compiler_real MATCHES "ccache")
    set(UWMS_USE_UNITY OFF)
  else()
    set(UWMS_USE_UNITY ON)
  endif()
elseif(UWMS_UNITY)
  set(UWMS_USE_UNITY ON)
else()
  set(UWMS_USE_UNITY OFF)
endif()
message(STATUS "uw_multislam: unity builds ${UWMS_USE_UNITY} (UWMS_UNITY=${UWMS_UNITY})")

# uwms_unity_build(TARGET target BATCH_SIZE n): the target's files in batches of n, in their order.
# uwms_unity_build(TARGET target GROUPS): the files' UNITY_GROUP source properties (CMake >= 3.18).
function(uwms_unity_build)
  cmake_parse_arguments(ARG "GROUPS" "TARGET;BATCH_SIZE" "" ${ARGN})
  if(NOT UWMS_USE_UNITY OR NOT TARGET ${ARG_TARGET})
    return()
  endif()
  if(ARG_GROUPS)
    if(CMAKE_VERSION VERSION_LESS 3.18)
      return()
    endif()
    set_target_properties(${ARG_TARGET} PROPERTIES UNITY_BUILD ON UNITY_BUILD_MODE GROUP)
  else()
    set_target_properties(${ARG_TARGET} PROPERTIES UNITY_BUILD ON UNITY_BUILD_BATCH_SIZE ${ARG_BATCH_SIZE})
  endif()
endfunction()
