/**
 * @file file_errors.h
 * @brief Why a file cannot be opened, in the words of a one-line error message.
 */
#pragma once

#include <string>
#include <system_error>

namespace pcr_pro {

/**
 * @brief The reason to give when a path does not lead to a file: a symlink loop (ELOOP: too many
 * levels of symbolic links) is reported as one, any other error of the file-system call with its
 * own text, and no error at all (the path simply is not there) as `not_found`.
 * @param[in] ec the error code of std::filesystem::exists() / status() on the path
 * @param[in] not_found the text for a missing file, e.g. "file not found"
 * @return e.g. "symlink loop (too many levels of symbolic links)"
 */
std::string missingFileReason(const std::error_code& ec, const std::string& not_found);

}  // namespace pcr_pro
