/**
 * @file param_schema.h
 * @brief One parameter schema per stage: for every parameter of an options struct its key, type,
 * default, range, unit and doc. The YAML and ROS-parameter loaders bind through it, each stage's
 * validate() checks its ranges with it, and pcr_pro_params prints the README's tables from it.
 *
 * The default is written once, in the options struct's member initialiser: the schema holds a
 * pointer to the member and reads the default from a default-constructed struct. So code that
 * builds options in C++ (tests, tools, library users) and code that reads a file see the same
 * default, and the schema cannot disagree with the struct.
 */
#pragma once

#include <cstdint>
#include <string>
#include <variant>
#include <vector>

#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

/// The accepted values of a numeric parameter; a double must also be finite.
struct ParamRange {
  enum class End { kNone, kClosed, kOpen };
  End lower_end = End::kNone;
  double lower = 0.0;
  End upper_end = End::kNone;
  double upper = 0.0;
  bool zero_too = false;  ///< 0 (off) is accepted besides the interval

  static ParamRange any() { return {}; }
  static ParamRange atLeast(double lo) { return {End::kClosed, lo, End::kNone, 0.0, false}; }
  static ParamRange above(double lo) { return {End::kOpen, lo, End::kNone, 0.0, false}; }
  static ParamRange closed(double lo, double hi) { return {End::kClosed, lo, End::kClosed, hi, false}; }
  static ParamRange open(double lo, double hi) { return {End::kOpen, lo, End::kOpen, hi, false}; }
  static ParamRange openClosed(double lo, double hi) { return {End::kOpen, lo, End::kClosed, hi, false}; }
  /// @return this range with 0 accepted as well ("0 = off")
  ParamRange orZero() const {
    ParamRange r = *this;
    r.zero_too = true;
    return r;
  }

  /// @return whether v is accepted (NaN and +-inf never are)
  bool contains(double v) const;
  /// @return "in (0, 1]", ">= 1", "> 0", "0 or >= 100", or "" when any value is accepted
  std::string text() const;
};

/// A parameter held as text in files (an enum, a choice): how to read and write it.
template <typename O>
struct TextParam {
  std::string (*get)(const O&);
  bool (*set)(O*, const std::string&);  ///< false: not one of the choices
  const char* choices;                  ///< e.g. "NISTER, STEWENIUS, SEVENPT or EIGHTPT"
};

/// One parameter of the options struct O.
template <typename O>
struct Param {
  using Member = std::variant<bool O::*, int O::*, std::int64_t O::*, std::uint32_t O::*, std::uint64_t O::*,
                              double O::*, std::string O::*, TextParam<O>>;
  std::string key;     ///< key inside the block; nested blocks with '.' ("stop.max_iterations")
  Member member;       ///< where the value lives in O
  ParamRange range;    ///< accepted values of a number (any for the other types)
  std::string unit;    ///< "px", "s", "-" (a ratio), "" (a count, a switch, a name)
  std::string doc;     ///< one line
};

/// How a stage's range errors read (each stage keeps the shape its messages always had).
enum class ParamMessage {
  kConfig,  ///< "<block>.<key> must be <range>" (configuration files)
  kNode,    ///< "<block><separator><key>: must be <range>, got <value>" (ROS parameters, simulator)
};

/// Every parameter of one stage (one YAML block or one group of ROS parameters).
template <typename O>
struct ParamSchema {
  std::string block;  ///< "matching", "icp", ... ("" at the top level)
  std::vector<Param<O>> params;
  ParamMessage message = ParamMessage::kConfig;
  char separator = '.';  ///< between block and key in messages ('/' for ROS parameter names)

  /// @return "<block><sep><key>" with '.' replaced by sep inside the key too
  std::string fullKey(const Param<O>& p, char sep) const;
};

/// The schema of the options struct O; each stage declares its specialisation beside its validate().
template <typename O>
const ParamSchema<O>& paramSchema();

/// A printable row of a parameter table.
struct ParamRow {
  std::string key, type, default_value, range, unit, doc;
};

namespace schema_detail {
std::string numberText(double v);
std::string joinKey(const std::string& block, const std::string& key, char sep);
[[noreturn]] void rangeError(ParamMessage style, const std::string& full_key, const ParamRange& r, double v);
}  // namespace schema_detail

template <typename O>
std::string ParamSchema<O>::fullKey(const Param<O>& p, char sep) const {
  return schema_detail::joinKey(block, p.key, sep);
}

/**
 * @brief Checks every numeric parameter of o against its range.
 * @throw InputError naming the first parameter out of range, in the stage's message shape
 */
template <typename O>
void checkRanges(const ParamSchema<O>& schema, const O& o) {
  for (const Param<O>& p : schema.params) {
    double v = 0.0;
    bool numeric = true;
    if (auto m = std::get_if<int O::*>(&p.member)) v = o.**m;
    else if (auto m = std::get_if<std::int64_t O::*>(&p.member)) v = static_cast<double>(o.**m);
    else if (auto m = std::get_if<std::uint32_t O::*>(&p.member)) v = o.**m;
    else if (auto m = std::get_if<std::uint64_t O::*>(&p.member)) v = static_cast<double>(o.**m);
    else if (auto m = std::get_if<double O::*>(&p.member)) v = o.**m;
    else numeric = false;
    if (numeric && !p.range.contains(v)) schema_detail::rangeError(schema.message, schema.fullKey(p, schema.separator), p.range, v);
  }
}

/// @return the type name of a parameter for tables ("double", "int", "bool", "string", or the choices)
template <typename O>
std::string paramType(const Param<O>& p) {
  switch (p.member.index()) {
    case 0: return "bool";
    case 1: case 2: case 3: case 4: return "int";
    case 5: return "double";
    case 6: return "string";
    default: return std::get<TextParam<O>>(p.member).choices;
  }
}

/// @return the value of p in o as YAML-like text ("0.75", "true", "STEWENIUS", "\"\"")
template <typename O>
std::string paramValueText(const Param<O>& p, const O& o) {
  if (auto m = std::get_if<bool O::*>(&p.member)) return o.**m ? "true" : "false";
  if (auto m = std::get_if<int O::*>(&p.member)) return std::to_string(o.**m);
  if (auto m = std::get_if<std::int64_t O::*>(&p.member)) return std::to_string(o.**m);
  if (auto m = std::get_if<std::uint32_t O::*>(&p.member)) return std::to_string(o.**m);
  if (auto m = std::get_if<std::uint64_t O::*>(&p.member)) return std::to_string(o.**m);
  if (auto m = std::get_if<double O::*>(&p.member)) return schema_detail::numberText(o.**m);
  if (auto m = std::get_if<std::string O::*>(&p.member)) return (o.**m).empty() ? "\"\"" : o.**m;
  return std::get<TextParam<O>>(p.member).get(o);
}

/// @return whether p has the same value in a and b (the text of a double reads back to it exactly)
template <typename O>
bool paramEqual(const Param<O>& p, const O& a, const O& b) {
  return paramValueText(p, a) == paramValueText(p, b);
}

/// @return the table rows of a schema, defaults read from a default-constructed O
template <typename O>
std::vector<ParamRow> paramRows(const ParamSchema<O>& schema, char sep = '.') {
  const O defaults{};
  std::vector<ParamRow> rows;
  for (const Param<O>& p : schema.params) {
    rows.push_back({schema.fullKey(p, sep), paramType(p), paramValueText(p, defaults), p.range.text(), p.unit, p.doc});
  }
  return rows;
}

/// @return the rows as a Markdown table (key, type, default, range, unit, description)
std::string markdownTable(const std::vector<ParamRow>& rows);

}  // namespace pcr_pro
