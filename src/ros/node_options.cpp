// Parameters of the merge node: loaded and validated in one place (see node_options.h).
#include "pcr_pro/ros/node_options.h"

#include <ros/param.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <set>
#include <sstream>

#include "pcr_pro/io/text_escape.h"
#include "pcr_pro/merge/seed.h"
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

// A list given as a string: `_agents:="[r1, r2]"` on a command line reaches the parameter server
// as the string "[r1, r2]" (roscpp types private arguments as int, double, bool or string only).
// It is read as YAML; anything but a list of scalars is an error naming the key.
std::vector<std::string> stringList(const std::string& key, const std::string& text) {
  YAML::Node node;
  try {
    node = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    fail(key, "must be a list of strings such as [agent_a, agent_b], got '" + text + "' (" + e.msg + ")");
  }
  if (!node.IsSequence()) fail(key, "must be a list of strings such as [agent_a, agent_b], got '" + text + "'");
  std::vector<std::string> out;
  for (std::size_t i = 0; i < node.size(); ++i) {
    if (!node[i].IsScalar()) fail(key, "element " + std::to_string(i) + " must be a string, got '" + text + "'");
    out.push_back(node[i].as<std::string>());
  }
  return out;
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
  // An XML-RPC int is 32 bits: wider options take it as it is.
  void read(const std::string& key, std::int64_t* value) const {
    if (!pnh_.hasParam(key)) return;
    int v = 0;
    read(key, &v);
    *value = v;
  }
  void read(const std::string& key, std::vector<std::string>* value) const {
    XmlRpc::XmlRpcValue v;
    if (!raw(key, &v)) return;
    if (v.getType() == XmlRpc::XmlRpcValue::TypeString) {
      *value = stringList(key, static_cast<std::string>(v));
      return;
    }
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

std::string scaledFrame(const std::string& frame_id) { return frame_id + "_scaled"; }

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
  for (const AgentOptions& a : o.agents) {
    for (const AgentOptions& b : o.agents) {
      if (a.frame_id == scaledFrame(b.frame_id)) {
        fail(a.name + "/frame_id", "'" + a.frame_id + "' is the scaled frame of agent " + b.name +
                                       "'s map (~aligned_cloud, tf): choose another");
      }
    }
  }
  if (o.queue_size < 1) fail("queue_size", "must be >= 1, got " + std::to_string(o.queue_size));
  if (o.seed < 0 || o.seed > 2147483647) fail("seed", "must be in [0, 2147483647], got " + std::to_string(o.seed));
  if (!(o.diagnostic_period >= 0.1 && o.diagnostic_period <= 60.0)) {
    fail("diagnostic_period", "must be in [0.1, 60] s, got " + std::to_string(o.diagnostic_period));
  }
  if (o.max_history_per_pair < 1) {
    fail("max_history_per_pair", "must be >= 1, got " + std::to_string(o.max_history_per_pair));
  }
  if (!o.g2o_file.empty()) {
    const std::filesystem::path file(o.g2o_file);
    std::error_code ec;
    if (std::filesystem::is_directory(file, ec)) fail("g2o_file", "'" + printable(o.g2o_file, 200) + "' is a directory");
    const std::filesystem::path dir = file.has_parent_path() ? file.parent_path() : std::filesystem::path(".");
    if (!std::filesystem::is_directory(dir, ec)) {
      fail("g2o_file", "directory '" + printable(dir.string(), 200) + "' does not exist");
    }
  }
  if (!o.auto_merge.target.empty() && !names.count(o.auto_merge.target)) {
    fail("auto_merge/target", "'" + o.auto_merge.target + "' is not one of ~agents");
  }
  try {
    validate(o.lsd);
    validate(o.limits);
    validate(o.merge);
    validate(o.auto_merge);
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
  p.read("seed", &o.seed);
  p.read("diagnostic_period", &o.diagnostic_period);
  p.read("max_history_per_pair", &o.max_history_per_pair);
  p.read("g2o_file", &o.g2o_file);
  p.read("auto_merge/enabled", &o.auto_merge.enabled);
  p.read("auto_merge/target", &o.auto_merge.target);
  p.read("auto_merge/min_keyframes", &o.auto_merge.min_keyframes);
  p.read("auto_merge/new_keyframes", &o.auto_merge.new_keyframes);
  p.read("auto_merge/after_graph_update", &o.auto_merge.after_graph_update);
  p.read("auto_merge/period", &o.auto_merge.period);

  // Unknown keys under ~ are typos: refuse them rather than silently using a default.
  std::set<std::string> known{"agents", "input", "queue_size", "publish_tf", "merge_config", "icp_config",
                              "lsd/scaled_depth_var_th", "lsd/abs_depth_var_th", "lsd/min_near_support",
                              "lsd/sparsify_factor", "max_keyframes_per_agent", "max_cloud_points_per_agent",
                              "seed", "diagnostic_period", "max_history_per_pair", "g2o_file", "auto_merge/enabled",
                              "auto_merge/target", "auto_merge/min_keyframes", "auto_merge/new_keyframes",
                              "auto_merge/after_graph_update", "auto_merge/period"};
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
  setSeed(&o.merge, static_cast<std::uint64_t>(o.seed));
  return o;
}

}  // namespace ros_bridge
}  // namespace pcr_pro
