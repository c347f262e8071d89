#include "pcr_pro/io/file_errors.h"

namespace pcr_pro {

std::string missingFileReason(const std::error_code& ec, const std::string& not_found) {
  if (!ec) return not_found;
  if (ec == std::errc::too_many_symbolic_link_levels) return "symlink loop (too many levels of symbolic links)";
  if (ec == std::errc::no_such_file_or_directory) return not_found;
  return not_found + " (" + ec.message() + ")";
}

}  // namespace pcr_pro
