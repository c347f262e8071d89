// merge_client: waits until a bag player (or any node) has finished, calls the merge node's
// ~merge service and prints the answer as YAML on stdout (demo.launch, docs/ros_interface.md).
// Private parameters:
//   service (string, default "merge_node/merge")  the MergeMaps service to call
//   wait_for_node (string, default "")            a node name; wait until it appeared and exited
//   settle_time (double, default 1.0) [s]         pause after that, for the last messages to arrive
//   timeout (double, default 120.0) [s]           give up waiting after this long
//   source_agent / target_agent (string, default "")  as in the request ("" = node default)
//   source_keyframe / target_keyframe (int, absent)   merge from this keyframe (use_*_keyframe);
//                                                 absent = the pipeline chooses the pair
//   truth_file (string, default "")               a truth.yaml: also print the edge's errors against it
//                                                 beside its reported uncertainty (truth_comparison.h)
//   output_file (string, default "")              also write the YAML to this file
//   end_launch (bool, default false)              when done, end the roslaunch that started this
//                                                 client as Ctrl-C would (SIGINT to the parent
//                                                 roslaunch process): demo.launch ends by itself
// Exit status: 0 merged, 1 not merged (the status says why), 2 no answer.
#include <ros/master.h>
#include <ros/ros.h>

#include <unistd.h>

#include <algorithm>
#include <csignal>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "pcr_pro/MergeMaps.h"
#include "pcr_pro/io/bundle.h"
#include "pcr_pro/io/truth_comparison.h"
#include "pcr_pro/ros/msg_conversion.h"

namespace {

bool nodeRunning(const std::string& name) {
  std::vector<std::string> nodes;
  if (!ros::master::getNodes(nodes)) return false;
  const std::string resolved = ros::names::resolve(name);
  return std::find(nodes.begin(), nodes.end(), resolved) != nodes.end();
}

template <typename T>
std::string list(const T& values, std::size_t n) {
  std::ostringstream s;
  s.precision(10);
  s << "[";
  for (std::size_t i = 0; i < n; ++i) s << (i ? ", " : "") << values[i];
  s << "]";
  return s.str();
}

// Ends the roslaunch that started this process as Ctrl-C would: roslaunch runs its nodes as its
// children, and a SIGINT makes it stop them all and exit without the red "REQUIRED process has
// died" banner of required="true". Only a parent whose command line names roslaunch is signalled.
void endLaunch() {
  const pid_t parent = getppid();
  std::ifstream cmdline("/proc/" + std::to_string(parent) + "/cmdline");
  const std::string command((std::istreambuf_iterator<char>(cmdline)), {});
  if (command.find("roslaunch") == std::string::npos) {
    ROS_WARN("end_launch: the parent process %d is not roslaunch; not ending it", static_cast<int>(parent));
    return;
  }
  ROS_INFO("done: ending the launch");
  kill(parent, SIGINT);
}

std::string quoted(const std::string& text) {
  std::string out = "\"";
  for (char c : text) out += (c == '"' || c == '\\') ? std::string("\\") + c : std::string(1, c);
  return out + "\"";
}

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "merge_client");
  ros::NodeHandle pnh("~");
  const std::string service = pnh.param<std::string>("service", "merge_node/merge");
  const std::string wait_for = pnh.param<std::string>("wait_for_node", "");
  const double settle = pnh.param("settle_time", 1.0);
  const double timeout = pnh.param("timeout", 120.0);
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(timeout);

  if (!wait_for.empty()) {
    ROS_INFO("waiting for node %s to start and finish", wait_for.c_str());
    bool seen = false;
    while (ros::ok() && ros::WallTime::now() < deadline) {
      const bool running = nodeRunning(wait_for);
      if (running) seen = true;
      if (seen && !running) break;
      ros::WallDuration(0.2).sleep();
    }
  }
  if (!ros::service::waitForService(service, ros::Duration(std::max(1.0, (deadline - ros::WallTime::now()).toSec())))) {
    ROS_ERROR("service %s did not come up within %.0f s", service.c_str(), timeout);
    return 2;
  }
  ros::WallDuration(settle).sleep();

  pcr_pro::MergeMaps srv;
  srv.request.source_agent = pnh.param<std::string>("source_agent", "");
  srv.request.target_agent = pnh.param<std::string>("target_agent", "");
  int id = 0;
  if ((srv.request.use_source_keyframe = pnh.getParam("source_keyframe", id))) srv.request.source_keyframe = id;
  if ((srv.request.use_target_keyframe = pnh.getParam("target_keyframe", id))) srv.request.target_keyframe = id;
  if (!ros::service::call(service, srv)) {
    ROS_ERROR("calling %s failed", service.c_str());
    return 2;
  }
  const pcr_pro::MergeMaps::Response& r = srv.response;
  std::ostringstream y;
  y.precision(10);
  y << "status: " << r.status_name << "\n";
  y << "message: " << quoted(r.message) << "\n";
  if (r.status == pcr_pro::MergeMaps::Response::OK) {
    const pcr_pro::MapEdge& e = r.edge;
    const auto& q = e.pose.pose.orientation;
    const auto& p = e.pose.pose.position;
    y << "edge:\n";
    y << "  source_agent: " << e.source_agent << "\n  target_agent: " << e.target_agent << "\n";
    y << "  source_frame: " << e.source_frame << "\n  target_frame: " << e.target_frame << "\n";
    y << "  source_keyframe: " << e.source_keyframe << "\n  target_keyframe: " << e.target_keyframe << "\n";
    y << "  scale: " << e.scale << "\n  scale_stddev: " << e.scale_stddev << "\n";
    y << "  rotation: [" << q.x << ", " << q.y << ", " << q.z << ", " << q.w << "]  # quaternion x y z w\n";
    y << "  translation: [" << p.x << ", " << p.y << ", " << p.z << "]\n";
    y << "  covariance: " << list(e.pose.covariance, 36) << "\n";
    y << "  information: " << list(e.information, 36) << "\n";
    y << "  fitness_rmse: " << e.fitness_rmse << "\n  correspondences: " << e.correspondences << "\n";
    const std::string truth_file = pnh.param<std::string>("truth_file", "");
    if (!truth_file.empty()) {
      try {
        const pcr_pro::BundleTruth truth = pcr_pro::loadBundleTruth(truth_file);
        const pcr_pro::ros_bridge::EdgeData edge = pcr_pro::ros_bridge::edgeFromMsg(e);
        y << pcr_pro::truthErrorsYaml(pcr_pro::compareWithTruth(edge.target_source, truth.target_source,
                                                                edge.covariance, edge.scale_stddev),
                                      truth_file);
      } catch (const std::exception& ex) {  // a bad truth file or edge: the edge is printed without errors
        ROS_ERROR("~truth_file: %s", ex.what());
      }
    }
  }
  std::fputs(y.str().c_str(), stdout);
  std::fflush(stdout);
  const std::string output_file = pnh.param<std::string>("output_file", "");
  if (!output_file.empty()) {
    std::ofstream out(output_file);
    out << y.str();
    if (!out) ROS_ERROR("cannot write %s", output_file.c_str());
  }
  if (pnh.param("end_launch", false)) endLaunch();
  return r.status == pcr_pro::MergeMaps::Response::OK ? 0 : 1;
}
