// Internal: the one YAML field reader of the core. Map bundles (bundle.yaml, truth.yaml), the
// configuration files (merge.yaml, icp.yaml) and the simulator's configuration read their YAML
// through it, so that every defect reads the same way, on one line:
//   "<file>: <field>: <what is wrong> (line N)"
// with the bytes of the file that a message quotes escaped (printable(), text_escape.h).
// The configuration loaders bind options structs through it with config_detail::Block
// (yaml_block.h); documents such as a bundle's keyframe list use its primitives directly.
#pragma once

#include <yaml-cpp/yaml.h>

#include <Eigen/Geometry>
#include <cstddef>
#include <limits>
#include <string>
#include <type_traits>
#include <vector>

#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {
namespace yaml_detail {

/// @return text on one line (control characters become spaces), cut at max_length with "..."
std::string oneLine(const std::string& text, std::size_t max_length = 400);

/// @return how a value reads in a message: "'<scalar, escaped>'", "null", "a list" or "a map"
std::string describe(const YAML::Node& node);

/// @return " (line N)" of a node read from text; "" for a node built in memory or absent
std::string lineOf(const YAML::Node& at);

/// @return the path of a map's child for messages: "parent.key", or "key" at the top level
std::string childKey(const std::string& parent, const std::string& key);

/// @return the path of a list's element for messages: "parent[index]"
std::string elementKey(const std::string& parent, std::size_t index);

/**
 * @brief Parses YAML text.
 * @return the document's root (null for an empty document)
 * @throw InputError "<origin>: YAML syntax error at line N, column C: <what>"
 */
YAML::Node parseYaml(const std::string& text, const std::string& origin);

/// One key of a map: its text, the key's node (where it stands) and its value.
struct Entry {
  std::string key;
  YAML::Node key_node;
  YAML::Node value;
};

/// The entries of one YAML map whose keys are plain and unique (FieldReader::fields()).
struct Fields {
  std::string path;  ///< field path of the map ("" for the document's top level)
  YAML::Node node;   ///< the map itself (null: an absent block, no entries)
  std::vector<Entry> entries;

  /// @return the value of key, or nullptr when the map does not have it
  const YAML::Node* find(const std::string& key) const;
};

/**
 * Validating accessors that turn every defect of a YAML document into an InputError naming the
 * file (origin), the field and the line: wrong types, quoted numbers, non-finite numbers, values
 * out of range, integers too large for their type, non-maps, duplicate keys (with both lines),
 * unknown keys (with the keys allowed), missing required keys.
 */
class FieldReader {
 public:
  /// @param[in] origin the file (or "what") every message starts with
  /// @param[out] warnings where warn() puts its lines; nullptr: warnings are dropped
  explicit FieldReader(std::string origin, std::vector<std::string>* warnings = nullptr);

  const std::string& origin() const { return origin_; }

  /// @throw InputError "<origin>: <field>: <problem> (line of at)" (no "field: " when field is "")
  [[noreturn]] void fail(const std::string& field, const YAML::Node& at, const std::string& problem) const;

  /// A warning "<origin>: <text> (line N)" for the caller, when it asked for warnings.
  void warn(const YAML::Node& at, const std::string& text) const;

  /// Checks that node is a map with plain, unique keys (a repeated key names both lines).
  Fields fields(const YAML::Node& node, const std::string& field) const;
  /// ... and that every key is one of allowed ("unknown key (allowed: a, b)").
  Fields fields(const YAML::Node& node, const std::string& field, const std::vector<std::string>& allowed) const;
  /// Refuses the first key of map that is not in allowed.
  void rejectUnknown(const Fields& map, const std::vector<std::string>& allowed) const;
  /// @return the value of a required key; "missing (required key)" at the map's line
  const YAML::Node& require(const Fields& map, const std::string& key) const;

  /// A finite number, not quoted; with a range, within it ("must be > 0, got 0").
  double number(const YAML::Node& node, const std::string& field,
                const ParamRange& range = ParamRange::any()) const;
  /// A number > 0.
  double positive(const YAML::Node& node, const std::string& field) const;
  /// A whole number that fits in long long, not quoted.
  long long integer(const YAML::Node& node, const std::string& field) const;
  /// A whole number within range that fits in T ("is too large (N)").
  template <typename T>
  T integerOf(const YAML::Node& node, const std::string& field, const ParamRange& range) const;
  /// Refuses a value outside range: "must be <range>, got <value>".
  void checkRange(const YAML::Node& at, const std::string& field, const ParamRange& range, double value) const;
  /// A scalar, as text; empty only when allow_empty.
  std::string text(const YAML::Node& node, const std::string& field, bool allow_empty = false) const;
  /// true or false (also yes/no, on/off: yaml-cpp's booleans).
  bool boolean(const YAML::Node& node, const std::string& field) const;
  /// Checks that node is a list: "must be a list of <of>, got ...".
  void list(const YAML::Node& node, const std::string& field, const std::string& of) const;
  /// A list of exactly size finite numbers.
  std::vector<double> numbers(const YAML::Node& node, const std::string& field, std::size_t size) const;
  Eigen::Vector3d vector3(const YAML::Node& node, const std::string& field) const;
  /// [x, y, z, w], not zero; normalised, with a warning when far from unit norm (plausibility.h).
  Eigen::Quaterniond quaternion(const YAML::Node& node, const std::string& field) const;

 private:
  /// A scalar that is not a quoted string, or an error "must be <what>, got ...".
  void checkPlainScalar(const YAML::Node& node, const std::string& field, const std::string& what) const;
  unsigned long long unsignedInteger(const YAML::Node& node, const std::string& field) const;

  std::string origin_;
  std::vector<std::string>* warnings_ = nullptr;
};

template <typename T>
T FieldReader::integerOf(const YAML::Node& node, const std::string& field, const ParamRange& range) const {
  static_assert(std::is_integral_v<T> && !std::is_same_v<T, bool>, "integerOf reads integers");
  if constexpr (std::is_unsigned_v<T>) {
    const unsigned long long value = unsignedInteger(node, field);
    checkRange(node, field, range, static_cast<double>(value));
    if (value > std::numeric_limits<T>::max()) fail(field, node, "is too large (" + std::to_string(value) + ")");
    return static_cast<T>(value);
  } else {
    const long long value = integer(node, field);
    checkRange(node, field, range, static_cast<double>(value));
    if (value > std::numeric_limits<T>::max()) fail(field, node, "is too large (" + std::to_string(value) + ")");
    if (value < std::numeric_limits<T>::min()) fail(field, node, "is too small (" + std::to_string(value) + ")");
    return static_cast<T>(value);
  }
}

}  // namespace yaml_detail
}  // namespace pcr_pro
