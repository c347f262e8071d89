#include "pcr_pro/io/cloud_io.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <vector>

#include "pcr_pro/io/file_errors.h"
#include "pcr_pro/io/text_escape.h"

namespace pcr_pro {
namespace {

// Upper bound on any count in a PCD header: keeps a corrupt header from asking for an absurd
// allocation. The configurable bound on points is InputLimits::max_cloud_points (<= this).
constexpr std::size_t kMaxPoints = static_cast<std::size_t>(kMaxCloudPointsCeiling);

// Largest expansion of LZF: a 3-byte back reference yields at most 264 bytes.
constexpr std::size_t kMaxLzfExpansion = 88;

std::string tooManyPoints(const std::string& origin, std::size_t points, const InputLimits& limits) {
  return origin + ": cloud has " + std::to_string(points) + " points, more than limits.max_cloud_points = " +
         std::to_string(limits.max_cloud_points);
}

// Only regular files are read: a device (/dev/zero), a FIFO or a directory would hang the reader
// or be misreported.
void requireRegularFile(const std::string& path) {
  std::error_code ec;
  const auto status = std::filesystem::status(path, ec);
  if (!std::filesystem::exists(status)) {
    throw InputError(path + ": " + missingFileReason(ec, "cannot open file (missing or unreadable)"));
  }
  if (!std::filesystem::is_regular_file(status)) throw InputError(path + ": not a regular file");
}

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

bool endsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

std::string readWholeFile(const std::string& path) {
  requireRegularFile(path);
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path + ": cannot open file (missing or unreadable)");
  std::ostringstream ss;
  ss << in.rdbuf();
  if (in.bad()) throw InputError(path + ": read error");
  return ss.str();
}

Cloud finitePoints(const std::vector<double>& xyz, const std::string& path) {
  const std::size_t n = xyz.size() / 3;
  if (n == 0) throw InputError(path + ": cloud is empty (no points)");
  Cloud cloud(3, static_cast<Eigen::Index>(n));
  Eigen::Index k = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double x = xyz[3 * i], y = xyz[3 * i + 1], z = xyz[3 * i + 2];
    if (std::isfinite(x) && std::isfinite(y) && std::isfinite(z)) cloud.col(k++) << x, y, z;
  }
  if (k == 0) throw InputError(path + ": cloud has no finite point (all NaN/Inf)");
  cloud.conservativeResize(3, k);
  return cloud;
}

// ---- PCD -------------------------------------------------------------------------------

struct PcdField {
  std::string name;
  int size = 4;
  char type = 'F';
  int count = 1;
  std::size_t offset = 0;  // byte offset inside a binary point record
};

struct PcdHeader {
  std::vector<PcdField> fields;
  std::size_t width = 0, height = 1, points = 0;
  bool have_points = false;
  std::string data;
  std::size_t point_step = 0;
};

double decodeBinary(const unsigned char* p, const PcdField& f) {
  switch (f.type) {
    case 'F':
      if (f.size == 4) { float v; std::memcpy(&v, p, 4); return v; }
      if (f.size == 8) { double v; std::memcpy(&v, p, 8); return v; }
      break;
    case 'I':
      if (f.size == 1) { int8_t v; std::memcpy(&v, p, 1); return v; }
      if (f.size == 2) { int16_t v; std::memcpy(&v, p, 2); return v; }
      if (f.size == 4) { int32_t v; std::memcpy(&v, p, 4); return v; }
      if (f.size == 8) { int64_t v; std::memcpy(&v, p, 8); return static_cast<double>(v); }
      break;
    case 'U':
      if (f.size == 1) { uint8_t v; std::memcpy(&v, p, 1); return v; }
      if (f.size == 2) { uint16_t v; std::memcpy(&v, p, 2); return v; }
      if (f.size == 4) { uint32_t v; std::memcpy(&v, p, 4); return v; }
      if (f.size == 8) { uint64_t v; std::memcpy(&v, p, 8); return static_cast<double>(v); }
      break;
  }
  return std::numeric_limits<double>::quiet_NaN();
}

std::size_t parseCount(const std::string& token, const std::string& path, const std::string& key) {
  std::size_t pos = 0;
  unsigned long long v = 0;
  try {
    v = std::stoull(token, &pos);
  } catch (const std::exception&) {
    throw InputError(path + ": PCD header field " + key + " is not a non-negative integer: '" + printable(token) + "'");
  }
  if (pos != token.size() || token[0] == '-') {
    throw InputError(path + ": PCD header field " + key + " is not a non-negative integer: '" + printable(token) + "'");
  }
  if (v > kMaxPoints) throw InputError(path + ": PCD header field " + key + " is too large: " + printable(token));
  return static_cast<std::size_t>(v);
}

// LZF decompression as used by PCD binary_compressed. Returns false on corrupt input.
bool lzfDecompress(const unsigned char* in, std::size_t in_len, unsigned char* out, std::size_t out_len) {
  std::size_t ip = 0, op = 0;
  while (ip < in_len) {
    unsigned int ctrl = in[ip++];
    if (ctrl < 32) {  // literal run of ctrl + 1 bytes
      const std::size_t len = ctrl + 1;
      if (ip + len > in_len || op + len > out_len) return false;
      std::memcpy(out + op, in + ip, len);
      ip += len;
      op += len;
    } else {  // back reference
      std::size_t len = ctrl >> 5;
      if (len == 7) {
        if (ip >= in_len) return false;
        len += in[ip++];
      }
      len += 2;
      if (ip >= in_len) return false;
      const std::size_t back = ((ctrl & 0x1f) << 8) + in[ip++] + 1;
      if (back > op || op + len > out_len) return false;
      for (std::size_t k = 0; k < len; ++k, ++op) out[op] = out[op - back];
    }
  }
  return op == out_len;
}

PcdHeader parsePcdHeader(const std::string& buf, std::size_t* data_start, const std::string& path) {
  PcdHeader h;
  std::vector<int> sizes, counts;
  std::vector<char> types;
  std::size_t pos = 0;
  while (pos < buf.size()) {
    std::size_t eol = buf.find('\n', pos);
    if (eol == std::string::npos) eol = buf.size();
    std::string line = buf.substr(pos, eol - pos);
    pos = std::min(eol + 1, buf.size());
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ls(line);
    std::string key;
    ls >> key;
    std::vector<std::string> values;
    for (std::string v; ls >> v;) values.push_back(v);
    if (key == "VERSION" || key == "VIEWPOINT") continue;
    if (key == "FIELDS" || key == "COLUMNS") {
      h.fields.clear();
      for (const auto& v : values) h.fields.push_back(PcdField{v});
    } else if (key == "SIZE") {
      for (const auto& v : values) sizes.push_back(static_cast<int>(parseCount(v, path, "SIZE")));
    } else if (key == "TYPE") {
      for (const auto& v : values) types.push_back(v.empty() ? '?' : v[0]);
    } else if (key == "COUNT") {
      for (const auto& v : values) counts.push_back(static_cast<int>(parseCount(v, path, "COUNT")));
    } else if (key == "WIDTH" && values.size() == 1) {
      h.width = parseCount(values[0], path, "WIDTH");
    } else if (key == "HEIGHT" && values.size() == 1) {
      h.height = parseCount(values[0], path, "HEIGHT");
    } else if (key == "POINTS" && values.size() == 1) {
      h.points = parseCount(values[0], path, "POINTS");
      h.have_points = true;
    } else if (key == "DATA" && values.size() == 1) {
      h.data = lower(values[0]);
      *data_start = pos;
      break;
    } else {
      throw InputError(path + ": not a PCD file (unexpected header line '" + printable(line, 40) + "')");
    }
  }
  if (h.data.empty()) throw InputError(path + ": not a PCD file (no DATA line)");
  if (h.fields.empty()) throw InputError(path + ": PCD header has no FIELDS");
  if (sizes.empty()) sizes.assign(h.fields.size(), 4);
  if (types.empty()) types.assign(h.fields.size(), 'F');
  if (counts.empty()) counts.assign(h.fields.size(), 1);
  if (sizes.size() != h.fields.size() || types.size() != h.fields.size() || counts.size() != h.fields.size()) {
    throw InputError(path + ": PCD header FIELDS/SIZE/TYPE/COUNT lengths disagree");
  }
  std::size_t offset = 0;
  for (std::size_t i = 0; i < h.fields.size(); ++i) {
    PcdField& f = h.fields[i];
    f.size = sizes[i];
    f.type = types[i];
    f.count = counts[i];
    if (f.count < 1 || f.count > 4096 || !(f.size == 1 || f.size == 2 || f.size == 4 || f.size == 8) ||
        !(f.type == 'F' || f.type == 'I' || f.type == 'U')) {
      throw InputError(path + ": PCD field '" + printable(f.name) + "' has an invalid SIZE/TYPE/COUNT");
    }
    f.offset = offset;
    offset += static_cast<std::size_t>(f.size) * f.count;
  }
  h.point_step = offset;
  if (!h.have_points) h.points = h.width * h.height;
  if (h.points > kMaxPoints) throw InputError(path + ": PCD POINTS too large");
  // WIDTH and HEIGHT are each at most kMaxPoints (2e8): their product fits 64 bits. A header whose
  // POINTS disagrees with them is inconsistent (which count holds is undefined; PCL refuses it too).
  if (h.have_points && h.width > 0 && h.points != h.width * h.height) {
    throw InputError(path + ": PCD header POINTS " + std::to_string(h.points) + " != WIDTH x HEIGHT = " +
                     std::to_string(h.width) + " x " + std::to_string(h.height));
  }
  return h;
}

// The x y z of every row of an ascii PCD body (from data_start), appended to xyz.
void readAsciiXyz(const std::string& buf, std::size_t data_start, const PcdHeader& h, const int (&idx)[3],
                  const std::string& path, std::vector<double>* xyz) {
  // Column index of each field's first element in an ascii row.
  std::vector<std::size_t> col(h.fields.size());
  std::size_t ncols = 0;
  for (std::size_t i = 0; i < h.fields.size(); ++i) {
    col[i] = ncols;
    ncols += h.fields[i].count;
  }
  std::size_t pos = data_start, row = 0;
  std::vector<std::string> tok;
  while (pos < buf.size() && row < h.points) {
    std::size_t eol = buf.find('\n', pos);
    if (eol == std::string::npos) eol = buf.size();
    std::istringstream ls(buf.substr(pos, eol - pos));
    pos = eol + 1;
    tok.clear();
    for (std::string t; ls >> t;) tok.push_back(t);
    if (tok.empty()) continue;
    if (tok.size() < ncols) {
      throw InputError(path + ": PCD ascii row " + std::to_string(row + 1) + " has " + std::to_string(tok.size()) +
                       " values, expected " + std::to_string(ncols));
    }
    for (int k : idx) {
      const std::string& t = tok[col[k]];
      char* end = nullptr;
      double v = std::strtod(t.c_str(), &end);
      if (end == t.c_str() || *end != '\0') {
        if (lower(t) == "nan") v = std::numeric_limits<double>::quiet_NaN();
        else throw InputError(path + ": PCD ascii row " + std::to_string(row + 1) + " has a non-number '" + printable(t) + "'");
      }
      xyz->push_back(v);
    }
    ++row;
  }
  if (row < h.points) {
    throw InputError(path + ": PCD truncated: " + std::to_string(row) + " of " + std::to_string(h.points) + " points");
  }
}

// The x y z of a binary PCD body (array of structures), appended to xyz.
void readBinaryXyz(const std::string& buf, std::size_t data_start, const PcdHeader& h, const int (&idx)[3],
                   const std::string& path, std::vector<double>* xyz) {
  const std::size_t need = h.points * h.point_step;
  if (buf.size() - data_start < need) {
    throw InputError(path + ": PCD binary data truncated (" + std::to_string(buf.size() - data_start) + " of " +
                     std::to_string(need) + " bytes)");
  }
  const auto* base = reinterpret_cast<const unsigned char*>(buf.data()) + data_start;
  for (std::size_t i = 0; i < h.points; ++i) {
    for (int k : idx) xyz->push_back(decodeBinary(base + i * h.point_step + h.fields[k].offset, h.fields[k]));
  }
}

// The x y z of a binary_compressed PCD body (LZF, structure of arrays), appended to xyz.
void readCompressedXyz(const std::string& buf, std::size_t data_start, const PcdHeader& h, const int (&idx)[3],
                       const std::string& path, std::vector<double>* xyz) {
  if (buf.size() - data_start < 8) throw InputError(path + ": PCD compressed data truncated (no size header)");
  uint32_t csize = 0, usize = 0;
  std::memcpy(&csize, buf.data() + data_start, 4);
  std::memcpy(&usize, buf.data() + data_start + 4, 4);
  const std::size_t need = h.points * h.point_step;
  if (usize != need) throw InputError(path + ": PCD compressed data size disagrees with the header");
  if (buf.size() - data_start - 8 < csize) throw InputError(path + ": PCD compressed data truncated");
  // Checked before allocating: csize bytes of LZF cannot expand beyond 88 x csize.
  if (need / kMaxLzfExpansion > csize) throw InputError(path + ": PCD compressed data is corrupt (sizes)");
  std::vector<unsigned char> raw(need);
  if (need > 0 &&
      !lzfDecompress(reinterpret_cast<const unsigned char*>(buf.data()) + data_start + 8, csize, raw.data(), need)) {
    throw InputError(path + ": PCD compressed data is corrupt");
  }
  // binary_compressed stores each field as a contiguous array (structure of arrays).
  std::vector<std::size_t> soa_offset(h.fields.size());
  std::size_t off = 0;
  for (std::size_t i = 0; i < h.fields.size(); ++i) {
    soa_offset[i] = off;
    off += h.points * h.fields[i].size * h.fields[i].count;
  }
  for (std::size_t i = 0; i < h.points; ++i) {
    for (int k : idx) {
      const PcdField& f = h.fields[k];
      xyz->push_back(decodeBinary(raw.data() + soa_offset[k] + i * f.size * f.count, f));
    }
  }
}

}  // namespace

Cloud parsePcd(const std::string& buf, const std::string& path, const InputLimits& limits) {
  if (buf.empty()) throw InputError(path + ": file is empty");
  std::size_t data_start = 0;
  const PcdHeader h = parsePcdHeader(buf, &data_start, path);
  if (h.points > static_cast<std::size_t>(std::max<std::int64_t>(limits.max_cloud_points, 0))) {
    throw InputError(tooManyPoints(path, h.points, limits) + " (PCD header POINTS/WIDTH x HEIGHT)");
  }
  int idx[3] = {-1, -1, -1};
  const char* const names[3] = {"x", "y", "z"};
  for (std::size_t i = 0; i < h.fields.size(); ++i) {
    for (int k = 0; k < 3; ++k) {
      if (h.fields[i].name != names[k]) continue;
      // Two fields of one name: which one holds is undefined (PCL reads the first), so the file
      // is refused rather than read either way.
      if (idx[k] >= 0) {
        throw InputError(path + ": PCD field '" + names[k] + "' appears twice in FIELDS (fields " +
                         std::to_string(idx[k] + 1) + " and " + std::to_string(i + 1) + ")");
      }
      idx[k] = static_cast<int>(i);
    }
  }
  if (idx[0] < 0 || idx[1] < 0 || idx[2] < 0) throw InputError(path + ": PCD has no x y z fields");
  std::vector<double> xyz;
  // Never reserve for more points than the data bytes can hold (a lying header costs nothing).
  const std::size_t data_bytes = buf.size() - data_start;
  xyz.reserve(3 * std::min<std::size_t>(h.points, data_bytes / std::max<std::size_t>(h.point_step, 1) + 1));

  if (h.data == "ascii") {
    readAsciiXyz(buf, data_start, h, idx, path, &xyz);
  } else if (h.data == "binary") {
    readBinaryXyz(buf, data_start, h, idx, path, &xyz);
  } else if (h.data == "binary_compressed") {
    readCompressedXyz(buf, data_start, h, idx, path, &xyz);
  } else {
    throw InputError(path + ": PCD DATA type '" + printable(h.data) + "' is not supported");
  }
  return finitePoints(xyz, path);
}

Cloud readPcd(const std::string& path, const InputLimits& limits) {
  return parsePcd(readWholeFile(path), path, limits);
}

namespace {

Cloud readCsvStream(std::istream& in, const std::string& path, const InputLimits& limits) {
  std::vector<double> xyz;
  int cols[3] = {0, 1, 2};
  std::string line;
  std::size_t line_no = 0;
  bool first_data = true;
  std::vector<std::string> tok;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    for (char& c : line) {
      if (c == ',' || c == ';' || c == '\t') c = ' ';
    }
    std::istringstream ls(line);
    tok.clear();
    for (std::string t; ls >> t;) tok.push_back(t);
    if (tok.empty() || tok[0][0] == '#') continue;
    // A first non-empty line whose first token is not a number is a header.
    if (first_data) {
      first_data = false;
      char* end = nullptr;
      std::strtod(tok[0].c_str(), &end);
      if (end == tok[0].c_str() || *end != '\0') {
        int found = 0;
        for (std::size_t i = 0; i < tok.size(); ++i) {
          const std::string name = lower(tok[i]);
          for (int k = 0; k < 3; ++k) {
            if (name == std::string(1, "xyz"[k])) {
              cols[k] = static_cast<int>(i);
              ++found;
            }
          }
        }
        if (found != 3) throw InputError(path + ": header line has no x, y, z columns");
        continue;
      }
    }
    const int need = std::max(cols[0], std::max(cols[1], cols[2])) + 1;
    if (static_cast<int>(tok.size()) < need) {
      throw InputError(path + ": line " + std::to_string(line_no) + " has " + std::to_string(tok.size()) +
                       " values, expected at least " + std::to_string(need));
    }
    for (int c : cols) {
      char* end = nullptr;
      double v = std::strtod(tok[c].c_str(), &end);
      if (end == tok[c].c_str() || *end != '\0') {
        throw InputError(path + ": line " + std::to_string(line_no) + " has a non-number '" + printable(tok[c]) + "'");
      }
      xyz.push_back(v);
    }
    if (xyz.size() / 3 > static_cast<std::size_t>(std::max<std::int64_t>(limits.max_cloud_points, 0))) {
      throw InputError(tooManyPoints(path, xyz.size() / 3, limits) + " (line " + std::to_string(line_no) + ")");
    }
  }
  if (in.bad()) throw InputError(path + ": read error");
  return finitePoints(xyz, path);
}

}  // namespace

Cloud readCsv(const std::string& path, const InputLimits& limits) {
  requireRegularFile(path);
  std::ifstream in(path);
  if (!in) throw InputError(path + ": cannot open file (missing or unreadable)");
  return readCsvStream(in, path, limits);
}

Cloud parseCsv(const std::string& text, const std::string& origin, const InputLimits& limits) {
  std::istringstream in(text);
  return readCsvStream(in, origin, limits);
}

Cloud readCloud(const std::string& path, const InputLimits& limits) {
  if (endsWith(lower(path), ".pcd")) return readPcd(path, limits);
  return readCsv(path, limits);
}

template <>
const ParamSchema<InputLimits>& paramSchema<InputLimits>() {
  using O = InputLimits;
  using R = ParamRange;
  static const ParamSchema<O> schema{"limits", {
      {"max_cloud_points", &O::max_cloud_points, R::closed(1, static_cast<double>(kMaxCloudPointsCeiling)), "points",
       "most points of one input cloud (PCD header, CSV rows)"},
      {"max_keyframes", &O::max_keyframes, R::atLeast(1), "", "most keyframes of one bundle"},
      {"max_image_pixels", &O::max_image_pixels, R::atLeast(1), "px", "most camera.width x camera.height"},
  }};
  return schema;
}

void validate(const InputLimits& limits) {
  checkRanges(paramSchema<InputLimits>(), limits);
}

void writePcd(const std::string& path, const Cloud& cloud) {
  std::ofstream out(path, std::ios::binary);
  if (!out) throw InputError(path + ": cannot write file");
  const Eigen::Index n = cloud.cols();
  out << "# .PCD v0.7 - Point Cloud Data file format (written by pcr_pro)\n"
      << "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
      << "WIDTH " << n << "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS " << n << "\nDATA binary\n";
  const Eigen::Matrix3Xf f = cloud.cast<float>();
  out.write(reinterpret_cast<const char*>(f.data()), static_cast<std::streamsize>(sizeof(float) * 3 * n));
  if (!out) throw InputError(path + ": write failed");
}

}  // namespace pcr_pro
