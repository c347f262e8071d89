#include "pcr_pro/io/param_schema.h"

#include <cmath>
#include <cstdlib>
#include <sstream>

namespace pcr_pro {

bool ParamRange::contains(double v) const {
  if (!std::isfinite(v)) return false;
  if (zero_too && v == 0.0) return true;
  if (lower_end == End::kClosed && !(v >= lower)) return false;
  if (lower_end == End::kOpen && !(v > lower)) return false;
  if (upper_end == End::kClosed && !(v <= upper)) return false;
  if (upper_end == End::kOpen && !(v < upper)) return false;
  return true;
}

std::string ParamRange::text() const {
  using schema_detail::numberText;
  std::string t;
  if (lower_end != End::kNone && upper_end != End::kNone) {
    t = std::string("in ") + (lower_end == End::kOpen ? "(" : "[") + numberText(lower) + ", " + numberText(upper) +
        (upper_end == End::kOpen ? ")" : "]");
  } else if (lower_end != End::kNone) {
    t = (lower_end == End::kOpen ? "> " : ">= ") + numberText(lower);
  } else if (upper_end != End::kNone) {
    t = (upper_end == End::kOpen ? "< " : "<= ") + numberText(upper);
  }
  return zero_too && !t.empty() ? "0 or " + t : t;
}

namespace schema_detail {

// Shortest decimal text that reads back to the same double; whole numbers without exponent.
std::string numberText(double v) {
  if (std::isfinite(v) && v == std::floor(v) && std::fabs(v) < 1e15) {
    std::ostringstream s;
    s << static_cast<long long>(v);
    return s.str();
  }
  for (int precision : {6, 12, 15, 17}) {
    std::ostringstream s;
    s.precision(precision);
    s << v;
    if (std::strtod(s.str().c_str(), nullptr) == v) return s.str();
  }
  return "nan";
}

std::string joinKey(const std::string& block, const std::string& key, char sep) {
  std::string k = key;
  for (char& c : k) {
    if (c == '.') c = sep;
  }
  return block.empty() ? k : block + sep + k;
}

void rangeError(ParamMessage style, const std::string& full_key, const ParamRange& r, double v) {
  if (style == ParamMessage::kNode) {
    throw InputError(full_key + ": must be " + r.text() + ", got " + numberText(v));
  }
  throw InputError(full_key + " must be " + r.text());
}

}  // namespace schema_detail

namespace {

// A table cell: '|' would end it.
std::string cell(const std::string& text) {
  std::string out;
  for (char c : text) out += c == '|' ? std::string("\\|") : std::string(1, c);
  return out;
}

}  // namespace

std::string markdownTable(const std::vector<ParamRow>& rows) {
  std::string t = "| key | type | default | range | unit | description |\n| --- | --- | --- | --- | --- | --- |\n";
  for (const ParamRow& r : rows) {
    t += "| `" + r.key + "` | " + cell(r.type) + " | `" + r.default_value + "` | " + r.range + " | " + cell(r.unit) +
         " | " + cell(r.doc) + " |\n";
  }
  return t;
}

}  // namespace pcr_pro
