# Shared settings for the build, test and demo scripts. Sourced, not run.
# The catkin workspace lives beside the repository, in <repo>_ws (a clone in ~/src/uw_multislam builds
# in ~/src/uw_multislam_ws), unless UWMS_WS says otherwise; the package is linked into its src/ so the
# repository root stays a plain catkin package. Not inside the repository: rosrun looks for a tool with
# find -L below the package's directory, and would find it again in a workspace there (and loop
# through the workspace's link back to the repository).
UWMS_REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd -P)
UWMS_WS=${UWMS_WS:-$(dirname "$UWMS_REPO")/$(basename "$UWMS_REPO")_ws}
# Debian's ROS Python modules live in /usr/lib/python3/dist-packages: a python3 from pyenv or
# a virtualenv earlier on PATH cannot import them, so /usr/bin goes first.
export PATH=/usr/bin:/bin:$PATH
# Logs of roslaunch / rostest go to the workspace, not to ~/.ros.
export ROS_HOME=${ROS_HOME:-$UWMS_WS/ros_home}
export ROS_LOG_DIR=${ROS_LOG_DIR:-$ROS_HOME/log}
