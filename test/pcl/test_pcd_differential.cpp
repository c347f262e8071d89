// Differential test of our PCD reader (pcr_pro::readPcd) against pcl::io::loadPCDFile on the PCD
// seeds of the fuzz corpus (test/fuzz/corpus/pcd/, written by test/fuzz/make_cloud_seeds.py) and on
// variants of them made here: where both accept a file they must read the same points; where only
// one does, the difference must be one of the known ones below, each with its reason.
#include <gtest/gtest.h>
#include <pcl/PCLPointCloud2.h>
#include <pcl/conversions.h>
#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>
#include <string>
#include <unistd.h>
#include <vector>

#include "pcr_pro/io/cloud_io.h"

namespace pcr_pro {
namespace {

namespace fs = std::filesystem;

std::string readBytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

void writeBytes(const fs::path& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out << bytes;
}

// The header's lines and the data after "DATA ...\n" of a PCD file.
struct PcdText {
  std::string header;  ///< up to and including the DATA line
  std::string data;
};
PcdText splitPcd(const std::string& bytes) {
  const std::size_t data_line = bytes.find("\nDATA ");
  const std::size_t end = bytes.find('\n', data_line + 1);
  return {bytes.substr(0, end + 1), bytes.substr(end + 1)};
}

std::string replaceOnce(std::string s, const std::string& from, const std::string& to) {
  const std::size_t at = s.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) s.replace(at, from.size(), to);
  return s;
}

// Each ascii row's first value (x) replaced by nan: in `rows` rows from the first.
std::string nanRows(const std::string& ascii_pcd, std::size_t rows) {
  PcdText t = splitPcd(ascii_pcd);
  std::istringstream in(t.data);
  std::string out, line;
  for (std::size_t r = 0; std::getline(in, line); ++r) {
    out += (r < rows ? "nan" + line.substr(line.find(' ')) : line) + "\n";
  }
  return t.header + out;
}

// The variants: name -> bytes. Seeds are taken as they are; the others are made from two seeds.
std::map<std::string, std::string> corpusAndVariants() {
  std::map<std::string, std::string> files;
  const fs::path dir = fs::path(PCR_PRO_FUZZ_CORPUS_DIR) / "pcd";
  for (const auto& entry : fs::directory_iterator(dir)) {
    if (entry.path().extension() == ".pcd") files[entry.path().filename().string()] = readBytes(entry.path());
  }
  EXPECT_GE(files.size(), 4u) << "the PCD seeds of " << dir;
  const std::string ascii = files.at("generated_ascii_normals.pcd");
  const std::string binary = files.at("generated_binary.pcd");
  files["variant_ascii_one_nan.pcd"] = nanRows(ascii, 1);
  files["variant_ascii_all_nan.pcd"] = nanRows(ascii, std::numeric_limits<std::size_t>::max());
  files["variant_binary_truncated.pcd"] = binary.substr(0, binary.size() - 4);
  files["variant_binary_points_below_width.pcd"] = replaceOnce(binary, "\nPOINTS 16\n", "\nPOINTS 15\n");
  files["variant_ascii_duplicate_x.pcd"] = replaceOnce(ascii, "FIELDS x y z normal_x", "FIELDS x y z x");
  files["variant_ascii_short_row.pcd"] = [&] {
    PcdText t = splitPcd(ascii);
    const std::size_t row_end = t.data.find('\n');
    return t.header + t.data.substr(0, t.data.rfind(' ', row_end)) + t.data.substr(row_end);
  }();
  return files;
}

// The files that only one reader accepts, and why. Anything else that differs fails the test.
struct KnownDifference {
  bool ours_accepts;
  bool pcl_accepts;
  const char* reason;
};
const std::map<std::string, KnownDifference>& knownDifferences() {
  static const std::map<std::string, KnownDifference> known = {
      {"variant_ascii_all_nan.pcd",
       {false, true,
        "ours is stricter by design: a cloud without a finite point is an input error (nothing to "
        "register), PCL returns it as a non-dense cloud of NaN"}},
      {"variant_ascii_duplicate_x.pcd",
       {false, true,
        "ours is stricter by design: with two fields 'x' which one holds is undefined, so the file is "
        "refused (PCL reads the first; our reader took the last before this test found it)"}},
      {"variant_ascii_short_row.pcd",
       {false, true,
        "ours is stricter by design: a row with fewer values than FIELDS/COUNT declare is malformed; PCL "
        "warns ('possibly malformed') and reads it anyway"}},
  };
  return known;
}

struct Outcome {
  bool accepted = false;
  std::string error;
  Cloud finite;  ///< the finite points read, in order
};

Outcome readOurs(const fs::path& path) {
  Outcome o;
  try {
    o.finite = readPcd(path.string());
    o.accepted = true;
  } catch (const InputError& e) {
    o.error = e.what();
  }
  return o;
}

Outcome readPcl(const fs::path& path) {
  Outcome o;
  pcl::PCLPointCloud2 blob;
  if (pcl::io::loadPCDFile(path.string(), blob) < 0) {
    o.error = "loadPCDFile failed";
    return o;
  }
  pcl::PointCloud<pcl::PointXYZ> cloud;
  pcl::fromPCLPointCloud2(blob, cloud);
  o.accepted = true;
  o.finite.resize(3, static_cast<Eigen::Index>(cloud.size()));
  Eigen::Index k = 0;
  for (const pcl::PointXYZ& p : cloud) {
    if (std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z)) o.finite.col(k++) = Eigen::Vector3d(p.x, p.y, p.z);
  }
  o.finite.conservativeResize(3, k);
  return o;
}

TEST(PcdDifferential, OurReaderAndPclAgreeOrDifferAsKnown) {
  const fs::path tmp = fs::temp_directory_path() / ("pcr_pro_pcd_differential_" + std::to_string(::getpid()));
  fs::create_directories(tmp);
  int both = 0, differing = 0;
  std::printf("%-40s %-8s %-8s %s\n", "file", "ours", "pcl", "points / reason");
  for (const auto& [name, bytes] : corpusAndVariants()) {
    const fs::path path = tmp / name;
    writeBytes(path, bytes);
    const Outcome ours = readOurs(path), theirs = readPcl(path);
    const auto known = knownDifferences().find(name);
    if (ours.accepted && theirs.accepted) {
      ++both;
      std::printf("%-40s %-8s %-8s %ld finite points\n", name.c_str(), "accepts", "accepts", long(ours.finite.cols()));
      EXPECT_EQ(known, knownDifferences().end()) << name << " is listed as a difference but both accept it";
      if (ours.finite.cols() != theirs.finite.cols()) {
        ADD_FAILURE() << name << ": ours " << ours.finite.cols() << " finite points, PCL " << theirs.finite.cols();
        continue;
      }
      // PCL reads every field into a float; ours reads binary floats exactly and ascii into a
      // double: each coordinate within PCL's float rounding (half an ulp <= eps * |value|).
      const Eigen::ArrayXXd bound =
          (std::numeric_limits<float>::epsilon() * ours.finite.array().abs()).max(std::numeric_limits<float>::min());
      EXPECT_TRUE(((ours.finite - theirs.finite).array().abs() <= bound).all()) << name;
      continue;
    }
    ++differing;
    const char* reason = known != knownDifferences().end()     ? known->second.reason
                         : !ours.accepted && !theirs.accepted ? "both refuse"
                                                              : "(not a known difference)";
    std::printf("%-40s %-8s %-8s %s%s%s\n", name.c_str(), ours.accepted ? "accepts" : "refuses",
                theirs.accepted ? "accepts" : "refuses", reason, ours.accepted ? "" : " | ours: ",
                ours.accepted ? "" : ours.error.c_str());
    if (!ours.accepted && !theirs.accepted) {
      EXPECT_EQ(known, knownDifferences().end()) << name << " is listed as a difference but both refuse it";
      EXPECT_NE(ours.error.find(path.string()), std::string::npos) << "our error names the file: " << ours.error;
      continue;
    }
    if (known == knownDifferences().end()) {
      ADD_FAILURE() << name << ": ours " << (ours.accepted ? "accepts" : "refuses (" + ours.error + ")") << ", PCL "
                    << (theirs.accepted ? "accepts" : "refuses") << ": not a known difference";
      continue;
    }
    EXPECT_EQ(ours.accepted, known->second.ours_accepts) << name;
    EXPECT_EQ(theirs.accepted, known->second.pcl_accepts) << name;
  }
  fs::remove_all(tmp);
  std::printf("%d files read alike by both, %d refused by one or both\n", both, differing);
  EXPECT_GE(both, 4);  // at least the seeds themselves
}

}  // namespace
}  // namespace pcr_pro
