#include "io/yaml_fields.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <utility>

#include "pcr_pro/io/plausibility.h"
#include "pcr_pro/io/text_escape.h"

namespace pcr_pro {
namespace yaml_detail {
namespace {

bool isQuoted(const YAML::Node& node) {
  // yaml-cpp tags quoted scalars "!" and explicit strings with the core str tag.
  return node.Tag() == "!" || node.Tag() == "tag:yaml.org,2002:str";
}

// The keys a map allows, for an "unknown key" message: bounded, so that a long list cannot push
// the line number out of the message.
std::string allowedText(const std::vector<std::string>& allowed) {
  std::string list;
  for (const std::string& name : allowed) list += (list.empty() ? "" : ", ") + name;
  return oneLine(list, 240);
}

// Configuration keys that moved: the old path (as childKey() spells it) and the new one. A file
// written for an earlier version then names the key to use instead of only listing the allowed
// ones. Old paths are never reused for another setting.
struct MovedKey {
  const char* old_path;
  const char* new_path;
};
constexpr MovedKey kMovedKeys[] = {
    // one setting for the merge and pcr_pro_icp (2026-12-04): the merge reads the ICP's options
    {"merge.register_noisier_as_target", "icp.sampling.register_noisier_as_target"},
};

// @return the key a moved key is now, or null
const char* movedTo(const std::string& path) {
  for (const MovedKey& m : kMovedKeys) {
    if (path == m.old_path) return m.new_path;
  }
  return nullptr;
}

}  // namespace

std::string oneLine(const std::string& text, std::size_t max_length) {
  std::string out;
  for (char c : text) {
    if (out.size() >= max_length) {
      out += "...";
      break;
    }
    out += (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) ? ' ' : c;
  }
  return out;
}

std::string describe(const YAML::Node& node) {
  switch (node.Type()) {
    case YAML::NodeType::Null:
      return "null";
    case YAML::NodeType::Scalar:
      return "'" + printable(node.Scalar(), 60) + "'";
    case YAML::NodeType::Sequence:
      return "a list";
    case YAML::NodeType::Map:
      return "a map";
    case YAML::NodeType::Undefined:
      break;
  }
  return "nothing";
}

std::string lineOf(const YAML::Node& at) {
  const YAML::Mark mark = at.Mark();
  return mark.is_null() ? std::string() : " (line " + std::to_string(mark.line + 1) + ")";
}

std::string childKey(const std::string& parent, const std::string& key) {
  return parent.empty() ? key : parent + "." + key;
}

std::string elementKey(const std::string& parent, std::size_t index) {
  return parent + "[" + std::to_string(index) + "]";
}

YAML::Node parseYaml(const std::string& text, const std::string& origin) {
  try {
    return YAML::Load(text);
  } catch (const YAML::ParserException& e) {
    throw InputError(oneLine(origin + ": YAML syntax error at line " + std::to_string(e.mark.line + 1) + ", column " +
                             std::to_string(e.mark.column + 1) + ": " + e.msg));
  } catch (const YAML::Exception& e) {
    throw InputError(oneLine(origin + ": cannot parse YAML: " + e.what()));
  }
}

const YAML::Node* Fields::find(const std::string& key) const {
  for (const Entry& entry : entries) {
    if (entry.key == key) return &entry.value;
  }
  return nullptr;
}

FieldReader::FieldReader(std::string origin, std::vector<std::string>* warnings)
    : origin_(std::move(origin)), warnings_(warnings) {}

void FieldReader::fail(const std::string& field, const YAML::Node& at, const std::string& problem) const {
  std::string message = origin_ + ": ";
  if (!field.empty()) message += field + ": ";
  throw InputError(oneLine(message + problem + lineOf(at)));
}

void FieldReader::warn(const YAML::Node& at, const std::string& text) const {
  if (warnings_ && !text.empty()) warnings_->push_back(oneLine(origin_ + ": " + text + lineOf(at)));
}

Fields FieldReader::fields(const YAML::Node& node, const std::string& field) const {
  if (!node.IsMap()) {
    fail(field, node, std::string(field.empty() ? "top level" : "value") + " must be a map, got " + describe(node));
  }
  Fields out;
  out.path = field;
  out.node = node;
  std::map<std::string, int> lines;  // key -> line of its first occurrence
  for (auto it = node.begin(); it != node.end(); ++it) {
    if (!it->first.IsScalar()) fail(field, it->first, "keys must be plain strings, got " + describe(it->first));
    const std::string key = it->first.Scalar();
    const int line = it->first.Mark().line + 1;
    const auto seen = lines.emplace(key, line);
    if (!seen.second) {
      fail(childKey(field, printable(key)), YAML::Node(),
           "duplicate key (lines " + std::to_string(seen.first->second) + " and " + std::to_string(line) + ")");
    }
    out.entries.push_back({key, it->first, it->second});
  }
  return out;
}

Fields FieldReader::fields(const YAML::Node& node, const std::string& field,
                           const std::vector<std::string>& allowed) const {
  Fields out = fields(node, field);
  rejectUnknown(out, allowed);
  return out;
}

void FieldReader::rejectUnknown(const Fields& map, const std::vector<std::string>& allowed) const {
  for (const Entry& entry : map.entries) {
    if (std::find(allowed.begin(), allowed.end(), entry.key) != allowed.end()) continue;
    if (const char* moved = movedTo(childKey(map.path, entry.key))) {
      fail(childKey(map.path, printable(entry.key)), entry.key_node,
           std::string("unknown key: this setting is now ") + moved + " (same meaning and default)");
    }
    fail(childKey(map.path, printable(entry.key)), entry.key_node, "unknown key (allowed: " + allowedText(allowed) + ")");
  }
}

const YAML::Node& FieldReader::require(const Fields& map, const std::string& key) const {
  const YAML::Node* value = map.find(key);
  if (value == nullptr) fail(childKey(map.path, key), map.node, "missing (required key)");
  return *value;
}

void FieldReader::checkPlainScalar(const YAML::Node& node, const std::string& field, const std::string& what) const {
  if (!node.IsScalar()) fail(field, node, "must be " + what + ", got " + describe(node));
  if (isQuoted(node)) fail(field, node, "must be " + what + ", got the string " + describe(node));
}

double FieldReader::number(const YAML::Node& node, const std::string& field, const ParamRange& range) const {
  checkPlainScalar(node, field, "a number");
  double value = 0.0;
  if (!YAML::convert<double>::decode(node, value)) fail(field, node, "must be a number, got " + describe(node));
  if (!std::isfinite(value)) fail(field, node, "must be finite, got " + describe(node));
  checkRange(node, field, range, value);
  return value;
}

double FieldReader::positive(const YAML::Node& node, const std::string& field) const {
  return number(node, field, ParamRange::above(0.0));
}

long long FieldReader::integer(const YAML::Node& node, const std::string& field) const {
  checkPlainScalar(node, field, "an integer");
  long long value = 0;
  if (!YAML::convert<long long>::decode(node, value)) fail(field, node, "must be an integer, got " + describe(node));
  return value;
}

unsigned long long FieldReader::unsignedInteger(const YAML::Node& node, const std::string& field) const {
  checkPlainScalar(node, field, "an integer");
  unsigned long long value = 0;
  if (YAML::convert<unsigned long long>::decode(node, value)) return value;
  const long long negative = integer(node, field);  // not a whole number at all: its error
  checkRange(node, field, ParamRange::atLeast(0.0), static_cast<double>(negative));
  fail(field, node, "must be an integer, got " + describe(node));
}

void FieldReader::checkRange(const YAML::Node& at, const std::string& field, const ParamRange& range,
                             double value) const {
  if (!range.contains(value)) {
    fail(field, at, "must be " + range.text() + ", got " + schema_detail::numberText(value));
  }
}

std::string FieldReader::text(const YAML::Node& node, const std::string& field, bool allow_empty) const {
  if (!node.IsScalar()) fail(field, node, "must be a string, got " + describe(node));
  if (!allow_empty && node.Scalar().empty()) fail(field, node, "must not be empty");
  return node.Scalar();
}

bool FieldReader::boolean(const YAML::Node& node, const std::string& field) const {
  bool value = false;
  if (!node.IsScalar() || !YAML::convert<bool>::decode(node, value)) {
    fail(field, node, "must be true or false, got " + describe(node));
  }
  return value;
}

void FieldReader::list(const YAML::Node& node, const std::string& field, const std::string& of) const {
  if (!node.IsSequence()) fail(field, node, "must be a list of " + of + ", got " + describe(node));
}

std::vector<double> FieldReader::numbers(const YAML::Node& node, const std::string& field, std::size_t size) const {
  const std::string of = std::to_string(size) + " numbers";
  list(node, field, of);
  if (node.size() != size) fail(field, node, "must be a list of " + of + ", got " + std::to_string(node.size()));
  std::vector<double> values;
  for (std::size_t i = 0; i < size; ++i) values.push_back(number(node[i], elementKey(field, i)));
  return values;
}

Eigen::Vector3d FieldReader::vector3(const YAML::Node& node, const std::string& field) const {
  const std::vector<double> v = numbers(node, field, 3);
  return Eigen::Vector3d(v[0], v[1], v[2]);
}

Eigen::Quaterniond FieldReader::quaternion(const YAML::Node& node, const std::string& field) const {
  const std::vector<double> v = numbers(node, field, 4);
  Eigen::Quaterniond q(v[3], v[0], v[1], v[2]);  // stored as x y z w
  if (!(q.norm() >= 1e-12)) fail(field, node, "zero quaternion (norm < 1e-12)");
  warn(node, quaternionNormWarning(q.norm(), field));
  q.normalize();
  return q;
}

}  // namespace yaml_detail
}  // namespace pcr_pro
