// Standalone odometry node: the uw_multislam/Odometry nodelet in its own process (as image_proc's
// nodes do). Same parameters, topics and behaviour as the nodelet loaded into a manager.
#include <nodelet/loader.h>
#include <ros/ros.h>

int main(int argc, char** argv) {
  ros::init(argc, argv, "odometry_node");
  nodelet::Loader loader(false);       // no manager services: a plain node
  const nodelet::M_string remappings;  // the process's own remappings already apply
  const nodelet::V_string nodelet_argv;
  if (!loader.load(ros::this_node::getName(), "uw_multislam/Odometry", remappings, nodelet_argv)) {
    ROS_FATAL("odometry: the uw_multislam/Odometry nodelet did not start (see the error above)");
    return 1;
  }
  ros::spin();
  return 0;
}
