// Internal helper of the configuration loaders: reads one YAML block into an options struct,
// naming "<origin>: <dotted.key>: <what>" in every error and rejecting unknown keys.
#pragma once

#include <yaml-cpp/yaml.h>

#include <set>
#include <string>
#include <utility>

#include "pcr_pro/registration/config.h"
#include "pcr_pro/geometry/types.h"

namespace pcr_pro {
namespace config_detail {

// Reads the keys of one YAML block into an options struct, tracking the dotted key path for
// error messages and rejecting keys the block does not know.
class Block {
 public:
  Block(const YAML::Node& node, std::string path, std::string origin)
      : node_(node), path_(std::move(path)), origin_(std::move(origin)) {
    if (node_ && !node_.IsNull() && !node_.IsMap()) fail(path_, "must be a map");
  }

  // Key path of a child for messages: "a.b", or "b" at the top level.
  std::string keyPath(const std::string& key) const { return path_.empty() ? key : path_ + "." + key; }

  template <typename T>
  void get(const std::string& key, T* value) {
    known_.insert(key);
    if (!node_ || node_.IsNull()) return;
    const YAML::Node v = node_[key];
    if (!v) return;
    try {
      *value = v.as<T>();
    } catch (const YAML::Exception&) {
      fail(keyPath(key), "has the wrong type");
    }
  }

  YAML::Node child(const std::string& key) {
    known_.insert(key);
    if (!node_ || node_.IsNull()) return YAML::Node();
    return node_[key];
  }

  void finish() const {
    if (!node_ || node_.IsNull()) return;
    for (const auto& kv : node_) {
      const std::string key = kv.first.as<std::string>();
      if (!known_.count(key)) fail(keyPath(key), "unknown key");
    }
  }

  [[noreturn]] void fail(const std::string& key, const std::string& what) const {
    throw InputError(origin_ + ": " + key + ": " + what);
  }

  const std::string& path() const { return path_; }
  const std::string& origin() const { return origin_; }

 private:
  YAML::Node node_;
  std::string path_;
  std::string origin_;
  std::set<std::string> known_;
};

// Runs a validate() and prefixes its message with the origin.
template <typename T>
void validateIn(const T& options, const std::string& origin) {
  try {
    validate(options);
  } catch (const InputError& e) {
    throw InputError(origin + ": " + e.what());
  }
}

/// Parses YAML text; @throw InputError "<origin>: invalid YAML at line N: ..."
YAML::Node parseYaml(const std::string& text, const std::string& origin);

/// Reads a whole text file; @throw InputError "<path>: cannot open configuration file"
std::string readConfigFile(const std::string& path);

/// Reads the geometric blocks (scale_detection, filters, icp, covariance) of a top-level map.
void loadRegistrationBlocks(Block* top, RegistrationOptions* options);

}  // namespace config_detail
}  // namespace pcr_pro
