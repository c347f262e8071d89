// libFuzzer target: the map bundle reader (loadBundle). Each input is written as bundle.yaml into
// a scratch bundle directory that also holds a small valid map.pcd and 8x6 keyframe images
// (keyframes/1.png grey, keyframes/1_depth.png 16-bit), so that mutated YAML reaches the file
// stage. Any input must load or end in one InputError, one line, naming a file.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <string>

#include "fuzz_common.h"
#include "pcr_pro/io/bundle.h"
#include "pcr_pro/io/cloud_io.h"

namespace {

std::filesystem::path scratchPath() {
  return std::filesystem::temp_directory_path() / ("pcr_pro_fuzz_bundle_" + std::to_string(::getpid()));
}

// Removes the scratch bundle when the fuzzer exits.
struct ScratchCleanup {
  ~ScratchCleanup() {
    std::error_code ec;
    std::filesystem::remove_all(scratchPath(), ec);
  }
} scratch_cleanup;

std::filesystem::path bundleDir() {
  static const std::filesystem::path dir = [] {
    const std::filesystem::path d = scratchPath();
    std::filesystem::create_directories(d / "keyframes");
    pcr_pro::Cloud cloud(3, 4);
    cloud << 0, 1, 0, 0, 0, 0, 1, 0, 1, 1, 1, 2;
    pcr_pro::writePcd((d / "map.pcd").string(), cloud);
    cv::Mat grey(6, 8, CV_8UC1);
    cv::randu(grey, 0, 255);
    cv::imwrite((d / "keyframes/1.png").string(), grey);
    cv::imwrite((d / "keyframes/1_depth.png").string(), cv::Mat(6, 8, CV_16UC1, cv::Scalar(1234)));
    return d;
  }();
  return dir;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pcr_pro;
  const std::filesystem::path dir = bundleDir();
  {
    std::ofstream out(dir / "bundle.yaml", std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  }
  InputLimits limits;
  limits.max_cloud_points = 1'000'000;
  limits.max_keyframes = 64;
  limits.max_image_pixels = 1'000'000;
  try {
    const AgentMap map = loadBundle(dir.string(), limits);
    fuzz::require(!map.keyframes.empty() && map.cloud.cols() >= 1, "loaded bundle without keyframes or points");
  } catch (const InputError& e) {
    const std::string message = e.what();
    fuzz::require(message.find('\n') == std::string::npos, "error message is not one line", message);
    fuzz::require(message.find(": ") != std::string::npos && !message.empty(), "error message names no file", message);
  }
  return 0;
}
