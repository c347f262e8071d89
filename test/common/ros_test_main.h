// The main() of a gtest binary that talks to a ROS master (rostest): gtest's and ROS's
// initialisation, a spinner for the callbacks while the tests wait, and a clean shutdown.
#pragma once

#include <gtest/gtest.h>
#include <ros/ros.h>

namespace pcr_pro {
namespace test {

/// Runs every test as ROS node `node_name`, with two spinner threads. @return RUN_ALL_TESTS()
inline int runRosTests(int argc, char** argv, const char* node_name) {
  ::testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, node_name);
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int result = RUN_ALL_TESTS();
  spinner.stop();
  ros::shutdown();
  return result;
}

}  // namespace test
}  // namespace pcr_pro
