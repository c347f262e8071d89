// merge_node: the pcr_pro merge node as an executable (see merge_node.h and docs/ros_interface.md).
#include <ros/ros.h>

#include <memory>

#include "pcr_pro/ros/merge_node.h"

int main(int argc, char** argv) {
  ros::init(argc, argv, "merge_node");
  ros::NodeHandle nh, pnh("~");
  // The node's constructor validates the merge options again (MergePipeline): an invalid one is
  // the caller's mistake and throws (error rule, pcr_pro.h), reported here like a bad parameter.
  std::unique_ptr<pcr_pro::ros_bridge::MergeNode> node;
  try {
    node = std::make_unique<pcr_pro::ros_bridge::MergeNode>(nh, pnh, pcr_pro::ros_bridge::loadNodeOptions(pnh));
  } catch (const pcr_pro::InputError& e) {
    ROS_FATAL("bad configuration, not starting: %s", e.what());
    return 1;
  }
  ros::spin();
  return 0;
}
