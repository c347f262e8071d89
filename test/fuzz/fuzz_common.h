// Shared by the libFuzzer targets of pcr_pro (test/fuzz): the properties every reader must keep
// on any input. A violated property aborts, which libFuzzer reports as a crash with its input.
#pragma once

#include <cstdio>
#include <cstdlib>
#include <string>

namespace pcr_pro {
namespace fuzz {

/// Aborts (a fuzzer finding) with `what` when `ok` is false.
inline void require(bool ok, const char* what, const std::string& detail = "") {
  if (ok) return;
  std::fprintf(stderr, "pcr_pro fuzz property violated: %s\n%s\n", what, detail.c_str());
  std::abort();
}

/// An InputError message must be one line that starts with the name of the input.
inline void requireOneLineNaming(const std::string& message, const std::string& origin) {
  require(message.find('\n') == std::string::npos, "error message is not one line", message);
  require(message.rfind(origin, 0) == 0, "error message does not start with the input's name", message);
}

}  // namespace fuzz
}  // namespace pcr_pro
