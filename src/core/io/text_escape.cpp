#include "pcr_pro/io/text_escape.h"

#include <algorithm>

namespace pcr_pro {

std::string printable(const std::string& text, std::size_t max_length) {
  static const char* kHex = "0123456789abcdef";
  std::string out;
  const std::size_t n = std::min(text.size(), max_length);
  for (std::size_t i = 0; i < n; ++i) {
    const unsigned char c = static_cast<unsigned char>(text[i]);
    if (c >= 0x20 && c < 0x7f) {
      out += static_cast<char>(c);
    } else {
      out += "\\x";
      out += kHex[c >> 4];
      out += kHex[c & 15];
    }
  }
  if (text.size() > max_length) out += "...";
  return out;
}

std::string csvField(const std::string& text) {
  if (text.find_first_of(",\"\r\n") == std::string::npos) return text;
  std::string out = "\"";
  for (const char c : text) {
    if (c == '"') out += '"';
    out += c;
  }
  return out + '"';
}

}  // namespace pcr_pro
