#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "pcr_pro/io/cloud_io.h"
#include "pcr_pro/io/text_escape.h"
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

// The expected point count and first point of a real text cloud, read here independently of
// cloud_io: the non-empty lines after the header (which ends with the first line starting with
// `header_end`; none when empty), and the first numbers of the first of them (',' or blanks).
struct TextCloudFacts {
  long points = 0;
  Eigen::Vector3d first = Eigen::Vector3d::Zero();
};

TextCloudFacts textCloudFacts(const std::string& path, const std::string& header_end) {
  std::ifstream in(path);
  TextCloudFacts facts;
  std::string line;
  if (!header_end.empty()) {
    while (std::getline(in, line) && line.rfind(header_end, 0) != 0) {
    }
  }
  while (std::getline(in, line)) {
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    if (facts.points++ == 0) {
      for (char& ch : line) ch = ch == ',' ? ' ' : ch;
      std::istringstream(line) >> facts.first.x() >> facts.first.y() >> facts.first.z();
    }
  }
  return facts;
}

TEST(CloudIo, ReadsRealCsvWithAndWithoutHeader) {
  PCR_PRO_REQUIRE_DATA("libpointmatcher_car");
  const std::string with_header = test::dataPath("libpointmatcher_car/car_cloud400.csv");  // x,y,z,nx,ny,nz
  const std::string without = test::dataPath("libpointmatcher_car/car_cloud401.csv");      // x y z, no header
  const TextCloudFacts fa = textCloudFacts(with_header, "x,"), fb = textCloudFacts(without, "");
  ASSERT_GT(fa.points, 1000);  // the scans hold about 25 000 points each (SOURCE.txt)
  ASSERT_GT(fb.points, 1000);
  const Cloud a = readCloud(with_header);
  EXPECT_EQ(a.cols(), fa.points);
  EXPECT_LT((a.col(0) - fa.first).norm(), 1e-9);
  const Cloud b = readCloud(without);
  EXPECT_EQ(b.cols(), fb.points);
  EXPECT_LT((b.col(0) - fb.first).norm(), 1e-9);
}

TEST(CloudIo, ReadsRealAsciiPcd) {
  PCR_PRO_REQUIRE_DATA("pcl_bunny");
  // bun0.pcd: PCD v0.7 with x y z + normals + curvature; bun4.pcd: PCD v.5, x y z; both ascii.
  const std::string v7 = test::dataPath("pcl_bunny/bun0.pcd"), v5 = test::dataPath("pcl_bunny/bun4.pcd");
  const TextCloudFacts fa = textCloudFacts(v7, "DATA"), fb = textCloudFacts(v5, "DATA");
  ASSERT_GT(fa.points, 100);  // a few hundred points each (SOURCE.txt)
  ASSERT_GT(fb.points, 100);
  const Cloud a = readCloud(v7);
  EXPECT_EQ(a.cols(), fa.points);
  EXPECT_LT((a.col(0) - fa.first).norm(), 1e-9);
  const Cloud b = readCloud(v5);
  EXPECT_EQ(b.cols(), fb.points);
  EXPECT_LT((b.col(0) - fb.first).norm(), 1e-9);
}

TEST(CloudIo, GeneratedFuzzSeedsAreValidClouds) {
  // The cloud readers' fuzz seeds (test/fuzz/make_cloud_seeds.py) are valid inputs, so fuzzing
  // starts from inputs that reach the end of each reader: every header variant parses.
  int seeds = 0;
  for (const char* kind : {"pcd", "csv"}) {
    for (const auto& entry : fs::directory_iterator(fs::path(PCR_PRO_FUZZ_CORPUS_DIR) / kind)) {
      if (entry.path().filename().string().rfind("generated_", 0) != 0) continue;
      SCOPED_TRACE(entry.path().string());
      const Cloud c = readCloud(entry.path().string());
      EXPECT_GE(c.cols(), 16);
      EXPECT_TRUE(c.allFinite());
      ++seeds;
    }
  }
  EXPECT_EQ(seeds, 6);
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
      // which x / which count holds would be undefined (test/pcl/test_pcd_differential.cpp)
      {"twox.pcd", "FIELDS x y z x\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 1\nPOINTS 1\nDATA ascii\n1 2 3 4\n"},
      {"points.pcd", "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nPOINTS 1\nDATA ascii\n1 2 3\n"},
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

// The bench's CSV writers quote their text fields with csvField(): a method name with a comma once
// split its row into one column too many.
TEST(CsvField, QuotesOnlyFieldsThatWouldSplitTheRow) {
  EXPECT_EQ(csvField("pcr_pro refined"), "pcr_pro refined");
  EXPECT_EQ(csvField(""), "");
  EXPECT_EQ(csvField("refinement, with jackknife"), "\"refinement, with jackknife\"");
  EXPECT_EQ(csvField("say \"hi\""), "\"say \"\"hi\"\"\"");
  EXPECT_EQ(csvField("two\nlines"), "\"two\nlines\"");
  EXPECT_EQ(csvField("cr\r"), "\"cr\r\"");
}

}  // namespace
}  // namespace pcr_pro
