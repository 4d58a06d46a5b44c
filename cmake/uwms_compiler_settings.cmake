# Compiler settings shared by the package's CMakeLists.txt and scripts/arm64/CMakeLists.txt (the
# ROS-free core cross-built for aarch64), so that both build the core alike.
set(CMAKE_CXX_STANDARD 17)
set(CMAKE_CXX_STANDARD_REQUIRED ON)
set(CMAKE_CXX_EXTENSIONS OFF)
if(NOT CMAKE_BUILD_TYPE AND NOT CMAKE_CONFIGURATION_TYPES)
  # SLAM runs on the vehicle: optimised code unless asked otherwise.
  set(CMAKE_BUILD_TYPE RelWithDebInfo CACHE STRING "Build type" FORCE)
endif()
add_compile_options(-Wall -Wextra)
option(UWMS_WERROR "Treat warnings as errors (the test command turns this on)" OFF)
if(UWMS_WERROR)
  add_compile_options(-Werror)
endif()
# Every shared library names what it needs: an undefined symbol (a declared, never defined
# method of a nodelet) fails the link, not the nodelet manager at load time.
string(APPEND CMAKE_SHARED_LINKER_FLAGS " -Wl,--no-undefined")
