// Parameters of the merge node: loaded and validated in one place (see node_options.h).
#include "pcr_pro/ros/node_options.h"

#include <ros/param.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <set>
#include <sstream>
#include <type_traits>
#include <variant>

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
  // An XML-RPC int is signed 32 bits: unsigned options take one >= 0.
  template <typename U, typename = std::enable_if_t<std::is_unsigned_v<U>>>
  void read(const std::string& key, U* value) const {
    if (!pnh_.hasParam(key)) return;
    int v = 0;
    read(key, &v);
    if (v < 0) fail(key, "must be >= 0, got " + std::to_string(v));
    *value = static_cast<U>(v);
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

// Reads one parameter of a schema from the parameter server (absent: the default stays).
template <typename O>
struct ParamServerBinder {
  const ParamReader& reader;
  const std::string& key;
  O* o;

  template <typename T>
  void operator()(T O::*member) const {
    reader.read(key, &(o->*member));
  }
  void operator()(const TextParam<O>& text) const {
    std::string value = text.get(*o);
    reader.read(key, &value);
    if (!text.set(o, value)) fail(key, std::string("must be ") + text.choices + ", got '" + value + "'");
  }
};

// Reads every parameter of O's schema, named "<block>/<key>" under ~, and adds their names to known.
template <typename O>
void bindParams(const ParamReader& reader, O* o, std::set<std::string>* known) {
  const ParamSchema<O>& schema = paramSchema<O>();
  for (const Param<O>& p : schema.params) {
    const std::string key = schema.fullKey(p, '/');
    known->insert(key);
    std::visit(ParamServerBinder<O>{reader, key, o}, p.member);
  }
}

}  // namespace

}  // namespace ros_bridge

template <>
const ParamSchema<ros_bridge::NodeOptions>& paramSchema<ros_bridge::NodeOptions>() {
  using O = ros_bridge::NodeOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"", {
      {"input",
       TextParam<O>{+[](const O& o) { return std::string(ros_bridge::inputModeName(o.input)); },
                    +[](O* o, const std::string& s) {
                      if (s != "pcr_pro" && s != "lsd_slam") return false;
                      o->input = s == "lsd_slam" ? ros_bridge::InputMode::kLsdSlam : ros_bridge::InputMode::kPcrPro;
                      return true;
                    },
                    "'pcr_pro' or 'lsd_slam'"},
       R::any(), "", "pcr_pro: X/keyframes + X/cloud; lsd_slam: X/lsd_slam/keyframes + X/lsd_slam/graph"},
      {"queue_size", &O::queue_size, R::atLeast(1), "messages", "subscriber queue length per topic"},
      {"publish_tf", &O::publish_tf, R::any(), "",
       "broadcast the static tf target_map -> <source_map>_scaled after each merge"},
      {"merge_config", &O::merge_config, R::any(), "", "merge configuration file (config/merge.yaml format); empty = defaults"},
      {"icp_config", &O::icp_config, R::any(), "",
       "registration configuration file (config/icp.yaml format) whose blocks replace merge_config's geometric stages"},
      {"seed", &O::seed, R::closed(0, 2147483647), "",
       "seed of every random stage of the merge: the same data and seed give the same edge bit for bit"},
      {"diagnostic_period", &O::diagnostic_period, R::closed(0.1, 60), "s", "diagnostics publishing period"},
      {"max_history_per_pair", &O::max_history_per_pair, R::atLeast(1), "edges",
       "most successful edges kept per agent pair in ~edge_history / ~edges; beyond it the oldest goes"},
      {"g2o_file", &O::g2o_file, R::any(), "",
       "after each successful merge, its pose graph is written to this g2o file (replacing the previous one); empty = off"},
  }, ParamMessage::kNode};
  return schema;
}

namespace ros_bridge {

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
    checkRanges(paramSchema<NodeOptions>(), o);
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

  std::set<std::string> known{"agents"};
  bindParams(p, &o, &known);
  bindParams(p, &o.lsd, &known);
  bindParams(p, &o.limits, &known);
  bindParams(p, &o.auto_merge, &known);

  // Unknown keys under ~ are typos: refuse them rather than silently using a default.
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

std::string nodeParameterTable() {
  std::vector<ParamRow> rows{
      {"agents", "list of strings", "[agent_a, agent_b]", "at least two", "",
       "unique relative names; topics X/... per agent; the first is the default merge target, the second the default "
       "source"},
      {"<agent>/frame_id", "string", "<agent>/map", "", "", "the agent's map frame: no leading slash, unique"}};
  const auto add = [&rows](const std::vector<ParamRow>& more) { rows.insert(rows.end(), more.begin(), more.end()); };
  add(paramRows(paramSchema<NodeOptions>(), '/'));
  add(paramRows(paramSchema<StoreLimits>(), '/'));
  add(paramRows(paramSchema<LsdFilterOptions>(), '/'));
  add(paramRows(paramSchema<AutoMergeOptions>(), '/'));
  return markdownTable(rows);
}

}  // namespace ros_bridge
}  // namespace pcr_pro
