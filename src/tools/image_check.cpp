#include "image_check.h"

#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <climits>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <opencv2/imgcodecs.hpp>
#include <vector>

#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/text_escape.h"

namespace pcr_pro {
namespace tools {
namespace {

std::uint32_t crc32(const unsigned char* data, std::size_t size, std::uint32_t crc) {
  static const std::vector<std::uint32_t> table = [] {
    std::vector<std::uint32_t> t(256);
    for (std::uint32_t n = 0; n < 256; ++n) {
      std::uint32_t c = n;
      for (int k = 0; k < 8; ++k) c = (c & 1u) ? 0xedb88320u ^ (c >> 1) : c >> 1;
      t[n] = c;
    }
    return t;
  }();
  for (std::size_t i = 0; i < size; ++i) crc = table[(crc ^ data[i]) & 0xffu] ^ (crc >> 8);
  return crc;
}

std::uint32_t bigEndian32(const unsigned char* p) {
  return (static_cast<std::uint32_t>(p[0]) << 24) | (static_cast<std::uint32_t>(p[1]) << 16) |
         (static_cast<std::uint32_t>(p[2]) << 8) | static_cast<std::uint32_t>(p[3]);
}

/**
 * Redirects the process's stderr (fd 2) to a temporary file while it lives, and hands back what
 * was written there. Image decoders print on stderr: libjpeg reports a truncated or damaged JPEG
 * ("Premature end of JPEG file", "Corrupt JPEG data: ...") as a warning and still returns an
 * image; libpng prints benign warnings. The offline tools must print exactly one line.
 */
class StderrCapture {
 public:
  StderrCapture() {
    std::fflush(stderr);
    sink_ = std::tmpfile();
    if (sink_ == nullptr) return;
    saved_ = ::dup(2);
    if (saved_ < 0 || ::dup2(::fileno(sink_), 2) < 0) restore();
  }
  ~StderrCapture() {
    restore();
    if (sink_ != nullptr) std::fclose(sink_);
  }
  StderrCapture(const StderrCapture&) = delete;
  StderrCapture& operator=(const StderrCapture&) = delete;

  /// Restores stderr and returns the first kMax bytes written while captured.
  std::string finish() {
    restore();
    std::string text;
    if (sink_ == nullptr) return text;
    std::rewind(sink_);
    constexpr std::size_t kMax = 300;
    char buffer[kMax];
    text.assign(buffer, std::fread(buffer, 1, kMax, sink_));
    return text;
  }

 private:
  void restore() {
    if (saved_ < 0) return;
    std::fflush(stderr);
    ::dup2(saved_, 2);
    ::close(saved_);
    saved_ = -1;
  }
  std::FILE* sink_ = nullptr;
  int saved_ = -1;
};

bool isJpeg(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  unsigned char magic[3] = {0, 0, 0};
  in.read(reinterpret_cast<char*>(magic), 3);
  return in && magic[0] == 0xff && magic[1] == 0xd8 && magic[2] == 0xff;
}

}  // namespace

std::string pngDefect(const std::string& path, cv::Size* size) {
  static const unsigned char kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  std::ifstream in(path, std::ios::binary);
  std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (bytes.size() < 8 || !std::equal(kSignature, kSignature + 8, bytes.begin())) return "";
  std::size_t at = 8;
  bool first = true;
  while (true) {
    if (bytes.size() - at < 12) return "truncated PNG";
    const std::uint32_t length = bigEndian32(&bytes[at]);
    const std::string type(reinterpret_cast<const char*>(&bytes[at + 4]), 4);
    if (length > bytes.size() - at - 12) return "truncated PNG (chunk " + printable(type) + ")";
    const std::uint32_t crc = crc32(&bytes[at + 4], 4u + length, 0xffffffffu) ^ 0xffffffffu;
    if (crc != bigEndian32(&bytes[at + 8 + length])) return "damaged PNG (bad CRC in chunk " + printable(type) + ")";
    if (first && type != "IHDR") return "damaged PNG (no IHDR chunk first)";
    if (first && length < 8) return "damaged PNG (IHDR chunk too short)";
    if (first) {
      const std::uint32_t width = bigEndian32(&bytes[at + 8]), height = bigEndian32(&bytes[at + 12]);
      if (width == 0 || height == 0 || width > INT_MAX || height > INT_MAX) return "damaged PNG (IHDR size)";
      *size = cv::Size(static_cast<int>(width), static_cast<int>(height));
    }
    first = false;
    at += 12u + length;
    if (type == "IEND") return "";
  }
}

cv::Mat readImageChecked(const std::string& path, const cv::Size& expected_size) {
  cv::Size png_size = expected_size;
  const std::string defect = pngDefect(path, &png_size);
  if (!defect.empty()) throw InputError(path + ": cannot read image: " + defect);
  if (png_size != expected_size) {
    throw InputError(path + ": image is " + std::to_string(png_size.width) + "x" + std::to_string(png_size.height) +
                     ", camera.width x camera.height is " + std::to_string(expected_size.width) + "x" +
                     std::to_string(expected_size.height));
  }
  cv::Mat image;
  std::string decoder_output;
  {
    StderrCapture capture;
    image = cv::imread(path, cv::IMREAD_UNCHANGED);  // a cv::Exception is the caller's to name
    decoder_output = capture.finish();
  }
  if (image.empty()) throw InputError(path + ": cannot read image");
  // libjpeg decodes a damaged JPEG with a warning only: that is a corrupt keyframe, not an image.
  // (Warnings of other decoders, e.g. libpng's about colour profiles, are benign and dropped.)
  while (!decoder_output.empty() && std::isspace(static_cast<unsigned char>(decoder_output.back()))) {
    decoder_output.pop_back();
  }
  if (!decoder_output.empty() && isJpeg(path)) {
    // One line, bounded: the decoder's text with control characters as spaces, cut at 300 bytes.
    std::string text = path + ": cannot read image: damaged JPEG (";
    for (char c : decoder_output) text += (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) ? ' ' : c;
    if (text.size() > 300) text = text.substr(0, 300) + "...";
    throw InputError(text + ")");
  }
  return image;
}

}  // namespace tools
}  // namespace pcr_pro
