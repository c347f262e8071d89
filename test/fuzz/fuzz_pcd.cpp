// libFuzzer target: the PCD reader (parsePcd, the in-memory form of readPcd). Any input must end in
// a cloud of finite points or in an InputError naming the input on one line: no crash, no other
// exception, no sanitizer report, no allocation beyond the limits.
#include <cstddef>
#include <cstdint>
#include <string>

#include "fuzz_common.h"
#include "pcr_pro/io/cloud_io.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pcr_pro;
  InputLimits limits;
  limits.max_cloud_points = 1'000'000;  // keeps one input's worst case well under -rss_limit_mb
  const std::string origin = "fuzz.pcd";
  try {
    const Cloud cloud = parsePcd(std::string(reinterpret_cast<const char*>(data), size), origin, limits);
    fuzz::require(cloud.cols() >= 1 && cloud.cols() <= limits.max_cloud_points, "cloud size out of bounds");
    fuzz::require(cloud.allFinite(), "cloud has a non-finite point");
  } catch (const InputError& e) {
    fuzz::requireOneLineNaming(e.what(), origin);
  }
  return 0;
}
