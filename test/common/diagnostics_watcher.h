// The merge node's /diagnostics as a test sees them: the latest status of every task, its values
// by key, and waiting for a value. Needs a ROS master (rostest) and a spinner.
#pragma once

#include <diagnostic_msgs/DiagnosticArray.h>
#include <ros/ros.h>

#include <map>
#include <mutex>
#include <string>

namespace pcr_pro {
namespace test {

class DiagnosticsWatcher {
 public:
  explicit DiagnosticsWatcher(ros::NodeHandle& nh)
      : sub_(nh.subscribe("/diagnostics", 50, &DiagnosticsWatcher::onDiagnostics, this)) {}

  /// The value of `key` in the latest status of the task whose name ends with `task`; "" when none.
  std::string value(const std::string& task, const std::string& key) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& [name, status] : latest_) {
      if (name.size() < task.size() || name.compare(name.size() - task.size(), task.size(), task) != 0) continue;
      for (const auto& kv : status.values) {
        if (kv.key == key) return kv.value;
      }
    }
    return "";
  }

  /// value() as an integer; -1 when there is none.
  long number(const std::string& task, const std::string& key) {
    const std::string v = value(task, key);
    return v.empty() ? -1 : std::stol(v);
  }

  /// Waits until value(task, key) == expected. @return false after `seconds` without it
  bool waitFor(const std::string& task, const std::string& key, const std::string& expected, double seconds = 20.0) {
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(seconds);
    while (ros::ok() && ros::WallTime::now() < end) {
      if (value(task, key) == expected) return true;
      ros::WallDuration(0.1).sleep();
    }
    return false;
  }

 private:
  void onDiagnostics(const diagnostic_msgs::DiagnosticArray::ConstPtr& msg) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& s : msg->status) latest_[s.name] = s;
  }
  std::mutex mutex_;
  std::map<std::string, diagnostic_msgs::DiagnosticStatus> latest_;
  ros::Subscriber sub_;
};

}  // namespace test
}  // namespace pcr_pro
