// Parameters of the merge node: loaded and validated in one place (see node_options.h).
#include "pcr_pro/ros/node_options.h"

#include <ros/param.h>

#include <algorithm>
#include <cctype>
#include <set>
#include <sstream>

#include "pcr_pro/registration/config.h"

namespace pcr_pro {
namespace ros_bridge {

namespace {

[[noreturn]] void fail(const std::string& key, const std::string& what) { throw InputError("~" + key + ": " + what); }

bool validRelativeName(const std::string& name) {
  if (name.empty() || !std::isalpha(static_cast<unsigned char>(name[0]))) return false;
  if (name.back() == '/' || name.find("//") != std::string::npos) return false;
  return std::all_of(name.begin(), name.end(),
                     [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '/'; });
}

const char* typeName(XmlRpc::XmlRpcValue::Type t) {
  switch (t) {
    case XmlRpc::XmlRpcValue::TypeBoolean: return "bool";
    case XmlRpc::XmlRpcValue::TypeInt: return "int";
    case XmlRpc::XmlRpcValue::TypeDouble: return "double";
    case XmlRpc::XmlRpcValue::TypeString: return "string";
    case XmlRpc::XmlRpcValue::TypeArray: return "list";
    case XmlRpc::XmlRpcValue::TypeStruct: return "map";
    default: return "other";
  }
}

// Typed optional reads: absent keeps *value; present with the wrong type is an error.
class ParamReader {
 public:
  explicit ParamReader(const ros::NodeHandle& pnh) : pnh_(pnh) {}

  bool raw(const std::string& key, XmlRpc::XmlRpcValue* v) const { return pnh_.hasParam(key) && pnh_.getParam(key, *v); }

  void read(const std::string& key, std::string* value) const {
    XmlRpc::XmlRpcValue v;
    if (!raw(key, &v)) return;
    if (v.getType() != XmlRpc::XmlRpcValue::TypeString) fail(key, std::string("must be a string, got ") + typeName(v.getType()));
    *value = static_cast<std::string>(v);
  }
  void read(const std::string& key, bool* value) const {
    XmlRpc::XmlRpcValue v;
    if (!raw(key, &v)) return;
    if (v.getType() != XmlRpc::XmlRpcValue::TypeBoolean) fail(key, std::string("must be a bool, got ") + typeName(v.getType()));
    *value = static_cast<bool>(v);
  }
  void read(const std::string& key, int* value) const {
    XmlRpc::XmlRpcValue v;
    if (!raw(key, &v)) return;
    if (v.getType() != XmlRpc::XmlRpcValue::TypeInt) fail(key, std::string("must be an int, got ") + typeName(v.getType()));
    *value = static_cast<int>(v);
  }
  void read(const std::string& key, double* value) const {
    XmlRpc::XmlRpcValue v;
    if (!raw(key, &v)) return;
    if (v.getType() == XmlRpc::XmlRpcValue::TypeInt) {
      *value = static_cast<int>(v);
    } else if (v.getType() == XmlRpc::XmlRpcValue::TypeDouble) {
      *value = static_cast<double>(v);
    } else {
      fail(key, std::string("must be a number, got ") + typeName(v.getType()));
    }
  }
  void read(const std::string& key, std::vector<std::string>* value) const {
    XmlRpc::XmlRpcValue v;
    if (!raw(key, &v)) return;
    if (v.getType() != XmlRpc::XmlRpcValue::TypeArray) fail(key, std::string("must be a list of strings, got ") + typeName(v.getType()));
    value->clear();
    for (int i = 0; i < v.size(); ++i) {
      if (v[i].getType() != XmlRpc::XmlRpcValue::TypeString) {
        fail(key, "element " + std::to_string(i) + " must be a string, got " + typeName(v[i].getType()));
      }
      value->push_back(static_cast<std::string>(v[i]));
    }
  }

 private:
  const ros::NodeHandle& pnh_;
};

}  // namespace

const char* inputModeName(InputMode mode) { return mode == InputMode::kLsdSlam ? "lsd_slam" : "pcr_pro"; }

void validate(const NodeOptions& o) {
  if (o.agents.size() < 2) fail("agents", "needs at least two agents, got " + std::to_string(o.agents.size()));
  std::set<std::string> names, frames;
  for (const AgentOptions& a : o.agents) {
    if (!validRelativeName(a.name)) {
      fail("agents", "'" + a.name + "' is not a valid relative name (letters, digits, _ and /, starting with a letter)");
    }
    if (!names.insert(a.name).second) fail("agents", "agent '" + a.name + "' is listed twice");
    if (a.frame_id.empty()) fail(a.name + "/frame_id", "must not be empty");
    if (a.frame_id[0] == '/') fail(a.name + "/frame_id", "no leading slash (tf2 frame ids are relative), got '" + a.frame_id + "'");
    if (a.frame_id.find(' ') != std::string::npos) fail(a.name + "/frame_id", "must not contain spaces");
    if (!frames.insert(a.frame_id).second) fail(a.name + "/frame_id", "frame '" + a.frame_id + "' is used by two agents");
  }
  if (o.queue_size < 1) fail("queue_size", "must be >= 1, got " + std::to_string(o.queue_size));
  try {
    validate(o.lsd);
    validate(o.limits);
    validate(o.merge);
  } catch (const InputError& e) {
    throw InputError(std::string("~") + e.what());
  }
}

NodeOptions loadNodeOptions(const ros::NodeHandle& pnh) {
  NodeOptions o;
  const ParamReader p(pnh);

  std::vector<std::string> agent_names;
  for (const AgentOptions& a : o.agents) agent_names.push_back(a.name);
  p.read("agents", &agent_names);
  o.agents.clear();
  for (const std::string& name : agent_names) {
    AgentOptions a{name, name + "/map"};
    if (validRelativeName(name)) p.read(name + "/frame_id", &a.frame_id);
    o.agents.push_back(a);
  }

  std::string input = inputModeName(o.input);
  p.read("input", &input);
  if (input == "pcr_pro") {
    o.input = InputMode::kPcrPro;
  } else if (input == "lsd_slam") {
    o.input = InputMode::kLsdSlam;
  } else {
    fail("input", "must be 'pcr_pro' or 'lsd_slam', got '" + input + "'");
  }
  p.read("queue_size", &o.queue_size);
  p.read("publish_tf", &o.publish_tf);
  p.read("merge_config", &o.merge_config);
  p.read("icp_config", &o.icp_config);
  p.read("lsd/scaled_depth_var_th", &o.lsd.scaled_depth_var_th);
  p.read("lsd/abs_depth_var_th", &o.lsd.abs_depth_var_th);
  p.read("lsd/min_near_support", &o.lsd.min_near_support);
  p.read("lsd/sparsify_factor", &o.lsd.sparsify_factor);
  p.read("max_keyframes_per_agent", &o.limits.max_keyframes);
  p.read("max_cloud_points_per_agent", &o.limits.max_cloud_points);

  // Unknown keys under ~ are typos: refuse them rather than silently using a default.
  std::set<std::string> known{"agents", "input", "queue_size", "publish_tf", "merge_config", "icp_config",
                              "lsd/scaled_depth_var_th", "lsd/abs_depth_var_th", "lsd/min_near_support",
                              "lsd/sparsify_factor", "max_keyframes_per_agent", "max_cloud_points_per_agent",
                              "diagnostic_period"};  // read by diagnostic_updater
  for (const AgentOptions& a : o.agents) known.insert(a.name + "/frame_id");
  std::vector<std::string> all;
  if (ros::param::getParamNames(all)) {
    const std::string prefix = pnh.getNamespace() + "/";
    for (const std::string& name : all) {
      if (name.compare(0, prefix.size(), prefix) != 0) continue;
      const std::string key = name.substr(prefix.size());
      if (!known.count(key)) fail(key, "unknown parameter (a typo?)");
    }
  }

  if (!o.merge_config.empty()) {
    try {
      o.merge = loadMergeConfig(o.merge_config);
    } catch (const InputError& e) {
      fail("merge_config", e.what());
    }
  }
  if (!o.icp_config.empty()) {
    try {
      o.merge.registration = loadRegistrationConfig(o.icp_config);
    } catch (const InputError& e) {
      fail("icp_config", e.what());
    }
  }
  validate(o);
  return o;
}

}  // namespace ros_bridge
}  // namespace pcr_pro
