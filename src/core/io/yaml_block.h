// Internal helper of the configuration loaders and the bundle reader: binds one YAML block into
// an options struct through its parameter schema, with the one field reader (yaml_fields.h), so
// that every error names "<origin>: <dotted.key>: <what> (line N)" and unknown keys are refused.
#pragma once

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <map>
#include <memory>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "pcr_pro/registration/config.h"
#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/param_schema.h"
#include "pcr_pro/io/text_escape.h"
#include "io/yaml_fields.h"

namespace pcr_pro {
namespace config_detail {

// One YAML block bound into an options struct through the one field reader (yaml_fields.h):
// tracks the dotted key path for messages, rejects duplicate keys when it is made (yaml-cpp would
// silently keep the first) and the keys the block does not know, reads each key with the reader's
// typed primitives (type, finite, range, fit). Errors read "<origin>: <key>: <what> (line N)".
class Block {
 public:
  /// kOptional: an absent key keeps its default, an absent or null block is empty (configurations);
  /// kRequired: every key read must be there and the block must be a map (documents: a bundle's camera).
  enum class Keys { kOptional, kRequired };

  Block(const YAML::Node& node, std::string path, std::string origin)
      : Block(yaml_detail::FieldReader(std::move(origin)), node, std::move(path)) {}
  Block(yaml_detail::FieldReader reader, const YAML::Node& node, std::string path, Keys keys = Keys::kOptional)
      : reader_(std::move(reader)), keys_(keys) {
    fields_.path = std::move(path);
    fields_.node = node;
    if (keys_ == Keys::kRequired || (node && !node.IsNull())) fields_ = reader_.fields(node, fields_.path);
  }

  // Key path of a child for messages: "a.b", or "b" at the top level.
  std::string keyPath(const std::string& key) const { return yaml_detail::childKey(fields_.path, key); }

  /// Reads key into *value (absent: kept, or "missing" when required); numbers must be in range.
  template <typename T>
  void get(const std::string& key, T* value, const ParamRange& range = ParamRange::any()) {
    const YAML::Node* v = find(key);
    if (v != nullptr) read(*v, keyPath(key), range, value);
  }

  /// @return the value of key (undefined when absent; "missing" when required), marked as known
  YAML::Node child(const std::string& key) {
    const YAML::Node* v = find(key);
    return v != nullptr ? *v : YAML::Node(YAML::NodeType::Undefined);
  }

  /// Refuses, now, every key not in keys (the message lists them).
  void allowOnly(const std::vector<std::string>& keys) const { reader_.rejectUnknown(fields_, keys); }

  /// Refuses the first key that no get() or child() asked for.
  void finish() const { reader_.rejectUnknown(fields_, known_); }

  [[noreturn]] void fail(const std::string& key, const std::string& what) const {
    reader_.fail(key, YAML::Node(), what);
  }
  [[noreturn]] void fail(const std::string& key, const std::string& what, const YAML::Node& at) const {
    reader_.fail(key, at, what);
  }

  /// The block's entries (empty for an absent optional block).
  const yaml_detail::Fields& fields() const { return fields_; }
  const std::string& path() const { return fields_.path; }
  const std::string& origin() const { return reader_.origin(); }
  const yaml_detail::FieldReader& reader() const { return reader_; }

 private:
  const YAML::Node* find(const std::string& key) {
    if (std::find(known_.begin(), known_.end(), key) == known_.end()) known_.push_back(key);
    const YAML::Node* v = fields_.find(key);
    if (v == nullptr && keys_ == Keys::kRequired) reader_.require(fields_, key);
    return v;
  }

  void read(const YAML::Node& v, const std::string& field, const ParamRange&, bool* out) const {
    *out = reader_.boolean(v, field);
  }
  void read(const YAML::Node& v, const std::string& field, const ParamRange&, std::string* out) const {
    *out = reader_.text(v, field, true);
  }
  void read(const YAML::Node& v, const std::string& field, const ParamRange& range, double* out) const {
    *out = reader_.number(v, field, range);
  }
  template <typename T, typename = std::enable_if_t<std::is_integral_v<T>>>
  void read(const YAML::Node& v, const std::string& field, const ParamRange& range, T* out) const {
    *out = reader_.integerOf<T>(v, field, range);
  }

  yaml_detail::FieldReader reader_;
  yaml_detail::Fields fields_;
  Keys keys_ = Keys::kOptional;
  std::vector<std::string> known_;  // in the order asked, for the "allowed" list
};

// Reads one parameter of a schema from a block: the type, then the range (with the line).
template <typename O>
class ParamBinder {
 public:
  ParamBinder(Block* block, const std::string& key, const Param<O>& param, O* o)
      : block_(block), key_(key), param_(param), o_(o) {}

  template <typename T>
  void operator()(T O::*member) {
    block_->get(key_, &(o_->*member), param_.range);
  }
  void operator()(const TextParam<O>& text) {
    std::string value = text.get(*o_);
    block_->get(key_, &value);
    if (!text.set(o_, value)) {
      block_->fail(block_->keyPath(key_), std::string("must be ") + text.choices + ", got '" + printable(value) + "'",
                   block_->child(key_));
    }
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
        sub = std::make_unique<Block>(block->reader(), block->child(prefix), block->keyPath(prefix));
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
  const YAML::Node root = yaml_detail::parseYaml(text, origin);
  if (!root || root.IsNull()) return;
  try {
    Block top(root, "", origin);  // not a map: "top level must be a map, got ..."
    load(&top);
    top.finish();
  } catch (const YAML::Exception& e) {
    // Safety net: a yaml-cpp error the reader's checks did not catch still names the file.
    throw InputError(yaml_detail::oneLine(origin + ": malformed configuration: " + e.msg));
  }
}

/// Reads the geometric blocks (scale_detection, filters, icp, covariance) of a top-level map.
void loadRegistrationBlocks(Block* top, RegistrationOptions* options);

}  // namespace config_detail
}  // namespace pcr_pro
