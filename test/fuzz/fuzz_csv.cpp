// libFuzzer target: the CSV / text cloud reader (parseCsv, the in-memory form of readCsv).
#include <cstddef>
#include <cstdint>
#include <string>

#include "fuzz_common.h"
#include "pcr_pro/io/cloud_io.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pcr_pro;
  InputLimits limits;
  limits.max_cloud_points = 1'000'000;
  const std::string origin = "fuzz.csv";
  try {
    const Cloud cloud = parseCsv(std::string(reinterpret_cast<const char*>(data), size), origin, limits);
    fuzz::require(cloud.cols() >= 1 && cloud.cols() <= limits.max_cloud_points, "cloud size out of bounds");
    fuzz::require(cloud.allFinite(), "cloud has a non-finite point");
  } catch (const InputError& e) {
    fuzz::requireOneLineNaming(e.what(), origin);
  }
  return 0;
}
