// Tool-side image reading for map bundles: the diagnostics that need process-wide state (fd 2)
// or go deeper than the core's decoder. The core's loadBundle() takes this reader as its
// ImageFileReader; the core itself decodes with OpenCV only (io/bundle.h).
#pragma once

#include <opencv2/core.hpp>

#include <string>

namespace pcr_pro {
namespace tools {

/**
 * @brief Walks the chunks of a PNG file (lengths, CRCs, IHDR first, IEND present). A truncated
 * or damaged PNG is reported here, with one line, instead of by libpng, which prints to stderr.
 * @param[in] path file path
 * @param[out] size the IHDR width and height when the file is a sound PNG (unchanged otherwise)
 * @return "" when the file is not a PNG or is sound, otherwise what is wrong
 */
std::string pngDefect(const std::string& path, cv::Size* size);

/**
 * @brief Reads an image file unchanged, for the offline tools: a PNG is walked first (pngDefect())
 * and refused from its header when its size is not `expected_size` (before it is decoded:
 * bounded memory); while OpenCV decodes, the process's stderr is captured, so that libjpeg's
 * warning about a truncated or corrupt JPEG (which still returns an image) becomes an error and
 * no decoder prints a second line. Single-threaded tools only: fd 2 is process-wide.
 * @param[in] path existing regular file
 * @param[in] expected_size the camera's image size [px]
 * @return the decoded image (never empty)
 * @throw InputError "<path>: <what is wrong>" (loadBundle() appends the bundle field)
 */
cv::Mat readImageChecked(const std::string& path, const cv::Size& expected_size);

}  // namespace tools
}  // namespace pcr_pro
