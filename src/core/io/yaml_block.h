// Internal helper of the configuration loaders: reads one YAML block into an options struct,
// naming "<origin>: <dotted.key>: <what>" in every error and rejecting unknown keys.
#pragma once

#include <yaml-cpp/yaml.h>

#include <map>
#include <memory>
#include <set>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "pcr_pro/registration/config.h"
#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {
namespace config_detail {

// Reads the keys of one YAML block into an options struct, tracking the dotted key path for
// error messages, rejecting duplicate keys (yaml-cpp would silently keep the first) and keys the
// block does not know. Errors read "<origin>: <key>: <what> (line N)".
class Block {
 public:
  Block(const YAML::Node& node, std::string path, std::string origin)
      : node_(node), path_(std::move(path)), origin_(std::move(origin)) {
    if (!node_ || node_.IsNull()) return;
    if (!node_.IsMap()) fail(path_, "must be a map", node_);
    std::map<std::string, int> lines;
    for (const auto& kv : node_) {
      const std::string key = kv.first.as<std::string>();
      const int line = kv.first.Mark().line + 1;
      const auto seen = lines.emplace(key, line);
      if (!seen.second) {
        throw InputError(origin_ + ": " + keyPath(key) + ": duplicate key (lines " + std::to_string(seen.first->second) +
                         " and " + std::to_string(line) + ")");
      }
    }
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
      fail(keyPath(key), "has the wrong type", v);
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
      if (!known_.count(key)) fail(keyPath(key), "unknown key", kv.first);
    }
  }

  [[noreturn]] void fail(const std::string& key, const std::string& what) const {
    throw InputError(origin_ + ": " + key + ": " + what);
  }
  [[noreturn]] void fail(const std::string& key, const std::string& what, const YAML::Node& at) const {
    throw InputError(origin_ + ": " + key + ": " + what + lineOf(at));
  }

  // " (line N)" of a node read from text, "" for a node built in memory.
  static std::string lineOf(const YAML::Node& at) {
    if (!at) return "";
    const YAML::Mark mark = at.Mark();
    return mark.is_null() ? "" : " (line " + std::to_string(mark.line + 1) + ")";
  }

  const std::string& path() const { return path_; }
  const std::string& origin() const { return origin_; }

 private:
  YAML::Node node_;
  std::string path_;
  std::string origin_;
  std::set<std::string> known_;
};

// Reads one parameter of a schema from a block: the type, then the range (with the line).
template <typename O>
class ParamBinder {
 public:
  ParamBinder(Block* block, const std::string& key, const Param<O>& param, O* o)
      : block_(block), key_(key), param_(param), o_(o) {}

  template <typename T>
  void operator()(T O::*member) {
    block_->get(key_, &(o_->*member));
    if constexpr (std::is_arithmetic_v<T> && !std::is_same_v<T, bool>) {
      if (!param_.range.contains(static_cast<double>(o_->*member))) {
        block_->fail(block_->keyPath(key_), "must be " + param_.range.text(), block_->child(key_));
      }
    }
  }
  void operator()(const TextParam<O>& text) {
    std::string value = text.get(*o_);
    block_->get(key_, &value);
    if (!text.set(o_, value)) block_->fail(block_->keyPath(key_), std::string("must be ") + text.choices, block_->child(key_));
  }

 private:
  Block* block_;
  const std::string& key_;
  const Param<O>& param_;
  O* o_;
};

// Reads every parameter of a schema from a block (nested keys "a.b" from its sub-block "a"),
// then rejects the keys the schema does not know in the sub-blocks (the caller finishes block).
template <typename O>
void bindParams(const ParamSchema<O>& schema, Block* block, O* o) {
  std::map<std::string, std::unique_ptr<Block>> nested;
  std::vector<std::string> order;
  for (const Param<O>& p : schema.params) {
    Block* b = block;
    std::string key = p.key;
    const std::size_t dot = key.find('.');
    if (dot != std::string::npos) {
      const std::string prefix = key.substr(0, dot);
      std::unique_ptr<Block>& sub = nested[prefix];
      if (!sub) {
        sub = std::make_unique<Block>(block->child(prefix), block->keyPath(prefix), block->origin());
        order.push_back(prefix);
      }
      b = sub.get();
      key = key.substr(dot + 1);
    }
    std::visit(ParamBinder<O>(b, key, p, o), p.member);
  }
  for (const std::string& prefix : order) nested[prefix]->finish();
}

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

// Reads the block of a stage from the top level (absent: the defaults), binds it through the
// stage's schema and validates it.
template <typename O>
O loadStage(Block* top) {
  const ParamSchema<O>& schema = paramSchema<O>();
  O o;
  Block b(top->child(schema.block), schema.block, top->origin());
  bindParams(schema, &b, &o);
  b.finish();
  validateIn(o, top->origin());
  return o;
}

// Parses configuration text and hands its top-level block to load(Block*), then rejects the keys
// load did not read. An empty document leaves everything at its defaults.
template <typename Load>
void loadTopLevel(const std::string& text, const std::string& origin, Load&& load) {
  const YAML::Node root = parseYaml(text, origin);
  if (!root || root.IsNull()) return;
  if (!root.IsMap()) throw InputError(origin + ": top level must be a map");
  try {
    Block top(root, "", origin);
    load(&top);
    top.finish();
  } catch (const YAML::Exception& e) {
    throw InputError(origin + ": malformed configuration: " + e.msg);
  }
}

/// Reads the geometric blocks (scale_detection, filters, icp, covariance) of a top-level map.
void loadRegistrationBlocks(Block* top, RegistrationOptions* options);

}  // namespace config_detail
}  // namespace pcr_pro
