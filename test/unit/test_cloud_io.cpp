#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>

#include "pcr_pro/io/cloud_io.h"
#include "test_helpers.h"

namespace pcr_pro {
namespace {

namespace fs = std::filesystem;

fs::path writeTemp(const std::string& name, const std::string& content) {
  const fs::path dir = fs::temp_directory_path() / ("pcr_pro_io_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const fs::path p = dir / name;
  std::ofstream(p, std::ios::binary) << content;
  return p;
}

std::string errorOf(const std::string& path) {
  try {
    readCloud(path);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(CloudIo, ReadsRealCsvWithAndWithoutHeader) {
  const Cloud a = readCloud(test::dataPath("libpointmatcher_car/car_cloud400.csv"));
  EXPECT_EQ(a.cols(), 24989);
  EXPECT_NEAR(a(0, 0), -3.5376, 1e-9);
  EXPECT_NEAR(a(2, 0), -1.37678, 1e-9);
  const Cloud b = readCloud(test::dataPath("libpointmatcher_car/car_cloud401.csv"));
  EXPECT_EQ(b.cols(), 25193);
  EXPECT_NEAR(b(0, 0), 2.6247663, 1e-9);
}

TEST(CloudIo, ReadsRealAsciiPcd) {
  const Cloud a = readCloud(test::dataPath("pcl_bunny/bun0.pcd"));  // x y z + normals + curvature
  EXPECT_EQ(a.cols(), 397);
  EXPECT_NEAR(a(0, 0), 0.0054215998, 1e-9);
  EXPECT_NEAR(a(1, 0), 0.11349, 1e-9);
  const Cloud b = readCloud(test::dataPath("pcl_bunny/bun4.pcd"));  // PCD v.5
  EXPECT_EQ(b.cols(), 361);
}

TEST(CloudIo, BinaryPcdRoundTrip) {
  std::mt19937 rng(1);
  const Cloud c = test::syntheticScene(1000, 5.0, rng);
  const fs::path p = writeTemp("round.pcd", "");
  writePcd(p.string(), c);
  const Cloud r = readCloud(p.string());
  ASSERT_EQ(r.cols(), c.cols());
  EXPECT_LT((r - c).cwiseAbs().maxCoeff(), 1e-6);
}

TEST(CloudIo, ReadsBinaryCompressedPcd) {
  // A binary_compressed PCD built by hand: fields stored as arrays, LZF stream of literal runs.
  const int n = 40;
  std::vector<float> soa(3 * n);
  for (int i = 0; i < n; ++i) {
    soa[i] = static_cast<float>(i);
    soa[n + i] = static_cast<float>(2 * i);
    soa[2 * n + i] = static_cast<float>(-i);
  }
  const std::string raw(reinterpret_cast<const char*>(soa.data()), soa.size() * 4);
  std::string lzf;
  for (std::size_t pos = 0; pos < raw.size(); pos += 32) {
    const std::size_t len = std::min<std::size_t>(32, raw.size() - pos);
    lzf += static_cast<char>(len - 1);
    lzf += raw.substr(pos, len);
  }
  uint32_t sizes[2] = {static_cast<uint32_t>(lzf.size()), static_cast<uint32_t>(raw.size())};
  std::string body(reinterpret_cast<const char*>(sizes), 8);
  body += lzf;
  const std::string header = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH " +
                             std::to_string(n) + "\nHEIGHT 1\nPOINTS " + std::to_string(n) + "\nDATA binary_compressed\n";
  const fs::path p = writeTemp("compressed.pcd", header + body);
  const Cloud c = readCloud(p.string());
  ASSERT_EQ(c.cols(), n);
  EXPECT_FLOAT_EQ(c(0, 7), 7.0f);
  EXPECT_FLOAT_EQ(c(1, 7), 14.0f);
  EXPECT_FLOAT_EQ(c(2, 7), -7.0f);
  // Corrupt stream: a back reference before the start.
  std::string bad = header + std::string(reinterpret_cast<const char*>(sizes), 8) + std::string("\xe0\xff\xff", 3);
  const fs::path q = writeTemp("corrupt.pcd", bad);
  EXPECT_THROW(readCloud(q.string()), InputError);
}

TEST(CloudIo, DropsNonFinitePoints) {
  const fs::path p = writeTemp("some_nan.csv", "1,2,3\nnan,1,1\n4,5,6\n1,inf,2\n");
  const Cloud c = readCloud(p.string());
  EXPECT_EQ(c.cols(), 2);
}

TEST(CloudIo, ErrorsNameTheFile) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"empty.pcd", ""},
      {"nan.pcd", "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\n"
                  "DATA ascii\nnan nan nan\n"},
      {"noxyz.pcd", "FIELDS a b c\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2 3\n"},
      {"short.pcd", "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\nHEIGHT 1\nPOINTS 3\nDATA ascii\n1 2 3\n"},
      {"huge.pcd", "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nPOINTS 99999999999\nDATA binary\n"},
      {"badsize.pcd", "FIELDS x y z\nSIZE 4 3 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nPOINTS 1\nDATA binary\n123456789012"},
      {"mismatch.pcd", "FIELDS x y z\nSIZE 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nPOINTS 1\nDATA ascii\n1 2 3\n"},
      {"nodata.pcd", "FIELDS x y z\nSIZE 4 4 4\n"},
      {"lzf.pcd", "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nPOINTS 1\nDATA weird\n"},
      {"text.csv", "1,2\n"},
      {"words.csv", "1,2,3\na,b,c\n"},
      {"header_only.csv", "x,y,z\n"},
      {"header_noz.csv", "x,y,w\n1,2,3\n"},
  };
  for (const auto& c : cases) {
    const fs::path p = writeTemp(c.first, c.second);
    const std::string e = errorOf(p.string());
    EXPECT_FALSE(e.empty()) << c.first;
    EXPECT_EQ(e.rfind(p.string(), 0), 0u) << c.first << ": " << e;
    EXPECT_EQ(e.find('\n'), std::string::npos) << c.first;
  }
  EXPECT_NE(errorOf("/nonexistent/x.pcd").find("/nonexistent/x.pcd"), std::string::npos);
}

}  // namespace
}  // namespace pcr_pro
