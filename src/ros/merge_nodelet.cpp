// pcr_pro/MergeNodelet: the merge node as a nodelet (same class as merge_node).
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>

#include <memory>
#include <stdexcept>

#include "pcr_pro/ros/merge_node.h"

namespace pcr_pro {
namespace ros_bridge {

class MergeNodelet : public nodelet::Nodelet {
 private:
  void onInit() override {
    // The constructor validates the merge options again (MergePipeline) and throws InputError
    // for an invalid one (error rule, pcr_pro.h): reported like a bad parameter.
    try {
      node_ = std::make_unique<MergeNode>(getNodeHandle(), getPrivateNodeHandle(),
                                          loadNodeOptions(getPrivateNodeHandle()));
    } catch (const InputError& e) {
      NODELET_FATAL("bad configuration, not starting: %s", e.what());
      throw std::runtime_error(std::string("pcr_pro/MergeNodelet: bad configuration: ") + e.what());
    }
  }

  std::unique_ptr<MergeNode> node_;
};

}  // namespace ros_bridge
}  // namespace pcr_pro

PLUGINLIB_EXPORT_CLASS(pcr_pro::ros_bridge::MergeNodelet, nodelet::Nodelet)
