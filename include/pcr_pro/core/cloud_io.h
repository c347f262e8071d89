/**
 * @file cloud_io.h
 * @brief Reading point clouds from PCD / CSV files and writing PCD files.
 *
 * The readers are our own (no PCL), strict and bounded: every defect is reported as an
 * InputError whose message names the file and what is wrong, never a crash.
 */
#pragma once

#include <string>

#include "pcr_pro/core/types.h"

namespace pcr_pro {

/**
 * @brief Reads a cloud, choosing the format from the extension (.pcd, otherwise CSV/text).
 * Points with a non-finite coordinate are dropped.
 * @param[in] path file path
 * @return the finite points (at least one)
 * @throw InputError missing/unreadable/malformed file, or no finite point ("empty" / "all-NaN")
 */
Cloud readCloud(const std::string& path);

/**
 * @brief Reads a PCD file (v0.5-0.7; DATA ascii, binary or binary_compressed; fields x y z of
 * any numeric type; other fields are skipped). Non-finite points are dropped.
 * @throw InputError as readCloud()
 */
Cloud readPcd(const std::string& path);

/**
 * @brief Reads a text cloud: one point per line, `x,y,z[,...]` or whitespace separated, with or
 * without a header line. With a header, the columns named x, y, z are used.
 * @throw InputError as readCloud()
 */
Cloud readCsv(const std::string& path);

/**
 * @brief Writes a binary PCD v0.7 file with float fields x y z.
 * @throw InputError when the file cannot be written
 */
void writePcd(const std::string& path, const Cloud& cloud);

}  // namespace pcr_pro
