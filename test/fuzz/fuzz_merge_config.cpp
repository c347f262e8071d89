// libFuzzer target: the merge configuration reader (parseMergeConfig: every stage block, the
// filters chain, the limits). Any text must give validated options or an InputError naming the
// origin on one line; a yaml-cpp exception escaping is a finding.
#include <cstddef>
#include <cstdint>
#include <string>

#include "fuzz_common.h"
#include "pcr_pro/merge/merge_pipeline.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace pcr_pro;
  const std::string origin = "fuzz_merge.yaml";
  try {
    const MergeOptions options = parseMergeConfig(std::string(reinterpret_cast<const char*>(data), size), origin);
    try {
      validate(options);  // what the parser returns must pass validation
    } catch (const InputError& e) {
      fuzz::require(false, "parsed options fail validation", e.what());
    }
  } catch (const InputError& e) {
    fuzz::require(std::string(e.what()).rfind(origin, 0) == 0, "error message does not name the origin", e.what());
  }
  return 0;
}
