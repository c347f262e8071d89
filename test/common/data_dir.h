// Where the tests and benchmarks find real data that the project does not ship.
//
// Real data (the 7-Scenes and slambook2 RGB-D frames, the libpointmatcher car scans, the PCL
// bunny; see ../shared/data/README.md) stays outside the repository. Its directory is the CMake
// cache variable PCR_PRO_DATA_DIR (default ../shared/data beside the source tree), compiled in as
// the default and overridden at run time by the environment variable of the same name. The
// two-agent cases built from it at build time (pcr_pro_make_real_cases) live in
// PCR_PRO_REAL_CASES_DIR (default BUILD/real_cases, environment variable of the same name).
//
// A test that needs a data set starts with
//   PCR_PRO_REQUIRE_DATA("libpointmatcher_car/car_cloud400.csv");
// and is skipped, with a one-line reason naming the missing path and the variable, when the data
// is absent. No gtest dependency here except in that macro, so the benchmarks can include it.
#pragma once

#include <cstdlib>
#include <filesystem>
#include <optional>
#include <string>

#ifndef PCR_PRO_DATA_DIR
#error "PCR_PRO_DATA_DIR must be defined by the build (CMake cache variable of the same name)"
#endif
#ifndef PCR_PRO_REAL_CASES_DIR
#define PCR_PRO_REAL_CASES_DIR ""
#endif

namespace pcr_pro {
namespace test {

namespace detail {
inline std::string fromEnvironment(const char* name, const char* compiled) {
  const char* value = std::getenv(name);
  return (value != nullptr && *value != '\0') ? std::string(value) : std::string(compiled);
}

inline std::optional<std::string> missing(const char* what, const std::string& path, const char* variable,
                                          const std::string& dir) {
  std::error_code ec;
  if (std::filesystem::exists(path, ec)) return std::nullopt;
  return std::string(what) + " absent: " + path + " does not exist (" + variable + "=" + dir + ")";
}
}  // namespace detail

/// @return the real-data directory: $PCR_PRO_DATA_DIR, else the directory the build was configured with
inline std::string dataDir() { return detail::fromEnvironment("PCR_PRO_DATA_DIR", PCR_PRO_DATA_DIR); }

/// @return dataDir() + "/" + relative
inline std::string dataPath(const std::string& relative) { return dataDir() + "/" + relative; }

/// @return the directory of the built real two-agent cases: $PCR_PRO_REAL_CASES_DIR, else BUILD/real_cases
inline std::string realCasesDir() { return detail::fromEnvironment("PCR_PRO_REAL_CASES_DIR", PCR_PRO_REAL_CASES_DIR); }

/// @return realCasesDir() + "/" + relative
inline std::string realCasePath(const std::string& relative) { return realCasesDir() + "/" + relative; }

/// @return a one-line reason when dataPath(relative) does not exist, nothing when it does
inline std::optional<std::string> missingData(const std::string& relative) {
  return detail::missing("real data", dataPath(relative), "PCR_PRO_DATA_DIR", dataDir());
}

/// @return a one-line reason when realCasePath(relative) does not exist, nothing when it does
inline std::optional<std::string> missingRealCase(const std::string& relative) {
  std::optional<std::string> reason =
      detail::missing("real two-agent cases", realCasePath(relative), "PCR_PRO_REAL_CASES_DIR", realCasesDir());
  if (reason) *reason += "; the build makes the cases when PCR_PRO_DATA_DIR holds the data";
  return reason;
}

}  // namespace test
}  // namespace pcr_pro

/// Skips the current gtest (GTEST_SKIP) with the reason when the data set path is absent.
#define PCR_PRO_REQUIRE_DATA(relative)                                          \
  do {                                                                          \
    if (const auto pcr_pro_missing_ = ::pcr_pro::test::missingData(relative)) { \
      GTEST_SKIP() << *pcr_pro_missing_;                                        \
    }                                                                           \
  } while (false)

/// Skips the current gtest when the built real case path (relative to realCasesDir()) is absent.
#define PCR_PRO_REQUIRE_REAL_CASE(relative)                                         \
  do {                                                                              \
    if (const auto pcr_pro_missing_ = ::pcr_pro::test::missingRealCase(relative)) { \
      GTEST_SKIP() << *pcr_pro_missing_;                                            \
    }                                                                               \
  } while (false)
