/**
 * @file cloud_io.h
 * @brief Reading point clouds from PCD / CSV files and writing PCD files.
 *
 * The readers are our own (no PCL), strict and bounded: every defect is reported as an
 * InputError whose message names the file and what is wrong, never a crash.
 */
#pragma once

#include <string>

#include "pcr_pro/io/input_limits.h"
#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

/**
 * @brief Reads a cloud, choosing the format from the extension (.pcd, otherwise CSV/text).
 * Points with a non-finite coordinate are dropped.
 * @param[in] path file path (a regular file: devices, FIFOs and directories are refused)
 * @param[in] limits resource bounds; a cloud with more than limits.max_cloud_points points is refused
 * @return the finite points (at least one)
 * @throw InputError missing/unreadable/malformed file, no finite point ("empty" / "all-NaN"), or
 *   more points than limits.max_cloud_points
 */
Cloud readCloud(const std::string& path, const InputLimits& limits = InputLimits());

/**
 * @brief Reads a PCD file (v0.5-0.7; DATA ascii, binary or binary_compressed; fields x y z of
 * any numeric type; other fields are skipped). Non-finite points are dropped.
 * @throw InputError as readCloud()
 */
Cloud readPcd(const std::string& path, const InputLimits& limits = InputLimits());

/**
 * @brief Reads a text cloud: one point per line, `x,y,z[,...]` or whitespace separated, with or
 * without a header line. With a header, the columns named x, y, z are used.
 * @throw InputError as readCloud()
 */
Cloud readCsv(const std::string& path, const InputLimits& limits = InputLimits());

/**
 * @brief As readPcd() from the bytes of a PCD file held in memory (e.g. a received file, a fuzzer).
 * @param[in] bytes the whole file
 * @param[in] origin name used in error messages in place of the path
 * @param[in] limits resource bounds
 * @throw InputError as readCloud(), naming `origin`
 */
Cloud parsePcd(const std::string& bytes, const std::string& origin, const InputLimits& limits = InputLimits());

/// @brief As readCsv() from text held in memory. @throw InputError as readCloud(), naming `origin`
Cloud parseCsv(const std::string& text, const std::string& origin, const InputLimits& limits = InputLimits());

/**
 * @brief Writes a binary PCD v0.7 file with float fields x y z.
 * @throw InputError when the file cannot be written
 */
void writePcd(const std::string& path, const Cloud& cloud);

}  // namespace pcr_pro
