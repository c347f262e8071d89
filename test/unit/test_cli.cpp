// Drives the pcr_pro_icp executable: exit statuses and one-line errors of the contract, and a
// registration with its outputs on a generated map (and on the real car scans when the real data
// is there).
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "common/cli_run.h"
#include "common/sim_worlds.h"
#include "pcr_pro/io/cloud_io.h"
#include "test_helpers.h"

namespace pcr_pro {
namespace {

namespace fs = std::filesystem;

using test::CliRun;

CliRun runIcp(const std::string& args) { return test::runCli(PCR_PRO_ICP_BIN, args, "pcr_pro_cli"); }

fs::path tempFile(const std::string& name, const std::string& content) {
  const fs::path dir = fs::temp_directory_path() / ("pcr_pro_cli_data_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  const fs::path p = dir / name;
  std::ofstream(p, std::ios::binary) << content;
  return p;
}

void expectInputError(const CliRun& r, const std::string& file) {
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find(file), std::string::npos) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << "not one line: " << r.err;
}

// A valid partner cloud for the bad-input cases, written here: a synthetic scene as CSV.
const std::string kGood = [] {
  std::mt19937 rng(3);
  const Cloud c = test::syntheticScene(2000, 5.0, rng);
  std::ostringstream csv;
  csv.precision(9);
  csv << "x,y,z\n";
  for (Eigen::Index i = 0; i < c.cols(); ++i) csv << c(0, i) << "," << c(1, i) << "," << c(2, i) << "\n";
  return tempFile("good.csv", csv.str()).string();
}();

TEST(Cli, MissingFile) {
  expectInputError(runIcp("--source /nonexistent/a.pcd --target " + kGood), "/nonexistent/a.pcd");
}

TEST(Cli, UnreadableFile) {
  const fs::path p = tempFile("unreadable.pcd", "x");
  fs::permissions(p, fs::perms::none);
  const bool root = ::geteuid() == 0;  // root reads anything: use a directory instead
  const std::string path = root ? p.parent_path().string() : p.string();
  expectInputError(runIcp("--source " + path + " --target " + kGood), path);
}

TEST(Cli, EmptyFile) {
  const fs::path p = tempFile("empty.pcd", "");
  expectInputError(runIcp("--source " + p.string() + " --target " + kGood), p.string());
  const fs::path q = tempFile("empty.csv", "x,y,z\n");
  expectInputError(runIcp("--source " + kGood + " --target " + q.string()), q.string());
}

TEST(Cli, AllNanCloud) {
  const fs::path p = tempFile("nan.pcd",
                              "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\n"
                              "POINTS 2\nDATA ascii\nnan nan nan\nnan 1 2\n");
  const CliRun r = runIcp("--source " + p.string() + " --target " + kGood);
  expectInputError(r, p.string());
  EXPECT_NE(r.err.find("NaN"), std::string::npos);
}

TEST(Cli, GarbageAndTruncatedFiles) {
  const fs::path g = tempFile("garbage.pcd", std::string("\x01\x02garbage\xff\n", 12));
  expectInputError(runIcp("--source " + g.string() + " --target " + kGood), g.string());
  const fs::path t = tempFile("truncated.pcd",
                              "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 100\nHEIGHT 1\n"
                              "POINTS 100\nDATA binary\n0123456789");
  expectInputError(runIcp("--source " + t.string() + " --target " + kGood), t.string());
}

TEST(Cli, BadUsage) {
  EXPECT_EQ(runIcp("--source " + kGood).status, 2);
  EXPECT_EQ(runIcp("--source " + kGood + " --target " + kGood + " --bogus").status, 2);
  EXPECT_EQ(runIcp("--source " + kGood + " --target " + kGood + " --initial \"1 2 3\"").status, 2);
  // A token that is not a number is named, with its place (it used to read as "expected 16 numbers").
  const CliRun nan_entry =
      runIcp("--source " + kGood + " --target " + kGood + " --initial \"1 0 0 nan 0 1 0 0 0 0 1 0 0 0 0 1\"");
  EXPECT_EQ(nan_entry.status, 2);
  EXPECT_NE(nan_entry.err.find("--initial: number 4 is 'nan', not a finite number"), std::string::npos) << nan_entry.err;
  EXPECT_NE(runIcp("--source " + kGood + " --target " + kGood + " --initial \"1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1x\"")
                .err.find("number 16 is '1x'"),
            std::string::npos);
  const fs::path cfg = tempFile("bad.yaml", "icp:\n  stop:\n    max_iterations: -1\n");
  expectInputError(runIcp("--source " + kGood + " --target " + kGood + " --config " + cfg.string()), cfg.string());
  EXPECT_EQ(runIcp("--help").status, 0);
}

// The generated demo world's agent_a map against itself moved by a known rigid motion (4 deg, a
// tenth of its RMS radius), from the identity. The source points are the target's own, so the
// result is exact up to where the ICP stops: an iteration that changes the rotation by less than
// 1e-4 rad and the translation by less than 1e-4 of the RMS radius (icp.stop) ends a few such
// steps from the answer; ten steps is the bound.
TEST(Cli, RegistersAGeneratedMapAndWritesOutputs) {
  const std::string target_file = test::simPath("demo/agent_a/map.pcd");
  const Cloud target = readCloud(target_file);
  const Eigen::Vector3d centre = target.rowwise().mean();
  const double radius = std::sqrt((target.colwise() - centre).squaredNorm() / static_cast<double>(target.cols()));
  std::mt19937 rng(5);
  const Sim3 motion(1.0, test::randomRotation(rng, test::rad(4.0)), 0.1 * radius * Eigen::Vector3d(0.6, -0.8, 0.0));
  const Cloud source = motion.inverse().apply(target);  // S_target_source = motion
  std::ostringstream csv;
  csv.precision(9);
  for (Eigen::Index i = 0; i < source.cols(); ++i) csv << source(0, i) << " " << source(1, i) << " " << source(2, i) << "\n";
  const fs::path source_file = tempFile("generated_moved.csv", csv.str());
  const fs::path out = fs::temp_directory_path() / ("pcr_pro_cli_gen_out_" + std::to_string(::getpid()));
  fs::remove_all(out);
  const CliRun r = runIcp("--source " + source_file.string() + " --target " + target_file + " --output " + out.string());
  ASSERT_EQ(r.status, 0) << r.err << r.out;
  const YAML::Node y = YAML::Load(r.out);
  EXPECT_EQ(y["status"].as<std::string>(), "OK");
  const auto q = y["rotation"].as<std::vector<double>>();
  const auto t = y["translation"].as<std::vector<double>>();
  const Sim3 estimate(y["scale"].as<double>(), Eigen::Quaterniond(q[3], q[0], q[1], q[2]).normalized(),
                      Eigen::Vector3d(t[0], t[1], t[2]));
  const TruthErrors e = compareWithTruth(estimate, motion, std::nullopt, std::nullopt);
  EXPECT_LT(e.rotation_deg, test::deg(10 * 1e-4)) << r.out;
  EXPECT_LT(e.translation, 10 * 1e-4 * radius) << r.out;
  EXPECT_NEAR(y["scale"].as<double>(), 1.0, 1e-12) << "no --estimate-scale: the scale stays 1";
  for (const char* key : {"covariance", "information", "fitness_rmse", "correspondences", "timings_ms"}) {
    EXPECT_TRUE(y[key]) << key;
  }
  std::ifstream yaml(out / "result.yaml");
  const std::string written((std::istreambuf_iterator<char>(yaml)), {});
  EXPECT_EQ(written, r.out);
  EXPECT_EQ(readPcd((out / "fused.pcd").string()).cols(), 2 * target.cols());
  fs::remove_all(out);
}

TEST(Cli, RegistersRealScansAndWritesOutputs) {
  PCR_PRO_REQUIRE_DATA("libpointmatcher_car");
  const std::string car400 = test::dataPath("libpointmatcher_car/car_cloud400.csv");
  const std::string car401 = test::dataPath("libpointmatcher_car/car_cloud401.csv");
  const fs::path out = fs::temp_directory_path() / ("pcr_pro_cli_out_" + std::to_string(::getpid()));
  fs::remove_all(out);
  const CliRun r = runIcp("--source " + car401 + " --target " + car400 + " --output " + out.string());
  ASSERT_EQ(r.status, 0) << r.err << r.out;
  EXPECT_NE(r.out.find("status: OK"), std::string::npos);
  for (const char* key : {"scale:", "rotation:", "translation:", "covariance:", "information:", "fitness_rmse:",
                          "correspondences:", "timings_ms:"}) {
    EXPECT_NE(r.out.find(key), std::string::npos) << key;
  }
  std::ifstream yaml(out / "result.yaml");
  const std::string written((std::istreambuf_iterator<char>(yaml)), {});
  EXPECT_EQ(written, r.out);
  const Cloud fused = readPcd((out / "fused.pcd").string());
  EXPECT_EQ(fused.cols(), readCloud(car400).cols() + readCloud(car401).cols());
}

}  // namespace
}  // namespace pcr_pro
