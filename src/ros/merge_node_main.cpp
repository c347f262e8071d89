// merge_node: the pcr_pro merge node as an executable (see merge_node.h and docs/ros_interface.md).
#include <ros/ros.h>

#include "pcr_pro/ros/merge_node.h"

int main(int argc, char** argv) {
  ros::init(argc, argv, "merge_node");
  ros::NodeHandle nh, pnh("~");
  pcr_pro::ros_bridge::NodeOptions options;
  try {
    options = pcr_pro::ros_bridge::loadNodeOptions(pnh);
  } catch (const pcr_pro::InputError& e) {
    ROS_FATAL("bad configuration, not starting: %s", e.what());
    return 1;
  }
  pcr_pro::ros_bridge::MergeNode node(nh, pnh, options);
  ros::spin();
  return 0;
}
