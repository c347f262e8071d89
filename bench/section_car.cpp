// make bench, section "car": the real libpointmatcher car scans with a known transform, the source
// expressed in other units so that the similarity has a known scale; cloud-only methods (ours
// without keyframes, PCL's rigid refiners from identity, Open3D's normalised FPFH recipe).
#include <fstream>
#include <sstream>

#include "common/data_dir.h"
#include "common/geometry_checks.h"
#include "pcr_pro/io/cloud_io.h"
#include "pcr_pro/registration/cloud_registration.h"
#include "pcr_pro/registration/scale_detection.h"
#include "suite.h"

namespace pcr_pro {
namespace bench {
namespace {

// Every method on the source expressed in units 1/s (S_target_source then has scale s).
std::vector<Row> carRuns(const Cloud& source0, const Cloud& target, const Sim3& truth0, double s, double extent) {
  std::vector<Row> rows;
  const Cloud source = source0 / s;
  const Sim3 truth = truth0 * Sim3(s, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
  PeerParams pp;
  pp.target_size = extent;
  pp.source_size = robustExtent(source, 0.05).size;
  RegistrationOptions reg;
  for (int m = 0; m < 2; ++m) {
    reg.icp.estimate_scale = m == 0;
    const double t0 = nowMs();
    const RegistrationReport rep = registerClouds(source, target, std::nullopt, reg);
    Row r = fromReport(rep, truth, extent, nowMs() - t0);
    r.method = m == 0 ? "pcr_pro registerClouds (scale detection + similarity ICP)" : "pcr_pro rigid ICP from identity";
    r.ratio = s;
    rows.push_back(r);
  }
  // PCL's rigid refiners from identity: the scans are consecutive (the truth is close to identity),
  // so they apply at s = 1; at other s they cannot find the scale and
  // take 10-20 s each, so they are not run there).
  const auto names = pclMethods();
  for (int k = 0; k < static_cast<int>(names.size()) && s == 1.0; ++k) {
    Row r = fromPeer(runPcl(k, source, target, pp), truth, extent);
    r.method = names[static_cast<std::size_t>(k)] + " (rigid, from identity)";
    r.ratio = s;
    rows.push_back(r);
  }
  if (haveOpen3d()) {
    Row r = fromPeer(runOpen3d(source, target, pp, Open3dSetting()), truth, extent);
    r.method = "Open3D FPFH + RANSAC + ICP (with scaling; " + Open3dSetting().name() + ")";
    r.ratio = s;
    rows.push_back(r);
  }
  return rows;
}

void carScans(Output& out, const std::vector<double>& scales) {
  // Real data (not shipped) from the real-data directory (PCR_PRO_DATA_DIR); the section says so
  // in the report when it is absent.
  if (const auto missing = test::missingData("libpointmatcher_car")) {
    std::FILE* md = out.open("car.md");
    std::fprintf(md, "Skipped: %s.\n\n", missing->c_str());
    std::fclose(md);
    return;
  }
  const std::string car = test::dataPath("libpointmatcher_car");
  const Cloud source0 = readCloud(car + "/car_cloud401.csv");
  const Cloud target = readCloud(car + "/car_cloud400.csv");
  const Sim3 truth0 = test::carGroundTruth(car + "/carCloudList.csv");
  const double extent = robustExtent(target, 0.05).size;
  std::vector<Row> rows;
  for (double s : scales) {
    const std::vector<Row> r = carRuns(source0, target, truth0, s, extent);
    rows.insert(rows.end(), r.begin(), r.end());
  }
  std::FILE* csv = out.open("car.csv");
  writeRows(csv, rows);
  std::fclose(csv);
  std::FILE* md = out.open("car.md");
  std::fprintf(md, "libpointmatcher car scans 401 → 400 (%ld / %ld points, extent %.2f m, ground truth from "
                   "carCloudList.csv); the source is expressed in units 1/s so that S_target_source has scale s. "
                   "No method gets an initial guess. Success: rotation < 1°, translation < 1 %% of the extent, "
                   "scale < 1 %%.\n\n| method | s | status | rotation [deg] | "
                   "translation [m] | scale error [%%] | success | time [ms] |\n|---|---|---|---|---|---|---|---|\n",
               static_cast<long>(source0.cols()), static_cast<long>(target.cols()), extent);
  for (const Row& r : rows) {
    const bool has = r.err.translation < 1e8;
    std::fprintf(md, "| %s | %g | %s | %s | %s | %s | %s | %.0f |\n", r.method.c_str(), r.ratio, r.status.c_str(),
                 has ? fmt(r.err.rotation_deg, 3).c_str() : "–", has ? fmt(r.err.translation, 4).c_str() : "–",
                 has ? fmt(100 * r.err.scale_rel, 2).c_str() : "–", r.ok ? "yes" : "no", r.ms);
  }
  std::fprintf(md, "\n");
  std::fclose(md);
}

}  // namespace

void sectionCar(Output& out, const SuiteConfig& config) {
  carScans(out, config.quick ? std::vector<double>{2.5} : std::vector<double>{1.0, 0.4, 2.5});
}

}  // namespace bench
}  // namespace pcr_pro
