// make bench, section "sweep": robustness of the merge on the slambook2 two-agent cases
// (BUILD/real_cases/slambook2, built from $PCR_PRO_DATA_DIR) against the scale ratio, the keyframe roll, the cloud density, cloud noise
// and outlier matches, with the ablations (no scale stage, no keyframe stage, rigid ICP). The
// peers are compared on the real and simulated cases (section_real_cases.cpp, section_simulated.cpp),
// in their best configuration; from identity on these bundles they never succeeded.
#include <functional>
#include <map>
#include <set>

#include "pcr_pro/frontend/feature_matching.h"
#include "pcr_pro/io/bundle.h"
#include "pcr_pro/merge/merge_pipeline.h"
#include "pcr_pro/registration/cloud_registration.h"
#include "pcr_pro/registration/scale_detection.h"
#include "common/data_dir.h"
#include "suite.h"

namespace pcr_pro {
namespace bench {
namespace {

struct SweepConfig {
  std::vector<double> ratios, rolls, sparsities;
  std::vector<std::string> variants;
  std::vector<double> noise_levels;  // σ of the added cloud noise, fraction of each cloud's extent
  std::vector<double> outlier_fractions;  // wrong matches / all matches fed to the keyframe front end
  int noise_seeds = 1;                    // draws per noise level and per outlier fraction
};

const char* kOurs = "pcr_pro (full)";
const char* kNoScale = "ICP from keyframe guess without scale (ablation: no scale stage)";
const char* kNoKeyframe = "pcr_pro without keyframe stage (scale detection + similarity ICP)";
const char* kRigid = "plain ICP from identity (ablation: rigid ICP only)";

// One slambook2 two-agent case with its truth.
struct BundlePair {
  BundleTruth truth;
  AgentMap target, source;
  double extent = 0.0;  ///< robust size of the target cloud
};

BundlePair loadBundlePair(const std::string& variant) {
  BundlePair p;
  const std::string dir = test::realCasePath("slambook2/" + variant);
  p.truth = loadBundleTruth(dir + "/truth.yaml");
  p.target = loadBundle(dir + "/" + p.truth.target_agent);
  p.source = loadBundle(dir + "/" + p.truth.source_agent);
  p.extent = robustExtent(p.target.cloud, 0.05).size;
  return p;
}

// Ablation: the keyframe pair and relative pose of the merge `mr`, scale forced to 1, rigid ICP.
Row noScaleAblation(const MergeResult& mr, const AgentMap& source, const AgentMap& target, const Sim3& expected,
                    double extent) {
  const MergeOptions defaults;
  Row nr;
  nr.method = kNoScale;

    if (mr.report.source_keyframe && mr.report.target_keyframe && mr.diagnostics.kalman_scale > 0.0) {
      const MapKeyframe* ks = nullptr;
      const MapKeyframe* kt = nullptr;
      for (const MapKeyframe& k : source.keyframes) {
        if (k.id == *mr.report.source_keyframe) ks = &k;
      }
      for (const MapKeyframe& k : target.keyframes) {
        if (k.id == *mr.report.target_keyframe) kt = &k;
      }
      const Sim3 cam_s(1.0, ks->pose.rotation(), ks->pose.translation());
      const Sim3 cam_t(1.0, kt->pose.rotation(), kt->pose.translation());
      const Sim3 kf = cam_t.inverse() * mr.diagnostics.initial * cam_s;
      const Sim3 guess = cam_t * Sim3(1.0, kf.rotation(), kf.translation()) * cam_s.inverse();
      RegistrationOptions reg = defaults.registration;
      reg.icp.estimate_scale = false;
      const double t0 = nowMs();
      const RegistrationReport rep = registerClouds(source.cloud, target.cloud, guess, reg);
      const Row tmp = fromReport(rep, expected, extent, nowMs() - t0);
      nr.status = tmp.status;
      nr.err = tmp.err;
      nr.ok = tmp.ok;
      nr.ms = tmp.ms;
    } else {
      nr.status = "NO_KEYFRAME_GUESS";
      nr.err = Errors{180.0, 1e9, 1e9};
    }
  return nr;
}

// The cloud-only ablations (no keyframe stage; rigid ICP from identity) on one (ratio, sparsity).
void cloudOnlyRuns(const AgentMap& source, const AgentMap& target, const Sim3& expected, double extent, double ratio,
                   double keep, std::vector<Row>& rows) {
  RegistrationOptions reg = MergeOptions().registration;
  for (int m = 0; m < 2; ++m) {
    reg.icp.estimate_scale = m == 0;
    const double t0 = nowMs();
    const RegistrationReport rep = registerClouds(source.cloud, target.cloud, std::nullopt, reg);
    Row r = fromReport(rep, expected, extent, nowMs() - t0);
    r.method = m == 0 ? kNoKeyframe : kRigid;
    r.variant = "clouds";
    r.ratio = ratio;
    r.sparsity = keep;
    rows.push_back(r);
  }
}

// Every (variant, ratio, sparsity, roll) merge with its no-scale ablation, and the cloud-only runs.
std::vector<Row> sweepRuns(const SweepConfig& sc) {
  std::vector<Row> rows;
  const MergeOptions defaults;
  for (const std::string& variant : sc.variants) {
    const BundlePair bp = loadBundlePair(variant);
    for (double ratio : sc.ratios) {
      const double factor = bp.truth.target_source.scale() / ratio;
      const Sim3 expected = bp.truth.target_source * Sim3(1.0 / factor, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
      const AgentMap source_scaled = rescaled(bp.source, factor);
      for (double keep : sc.sparsities) {
        AgentMap target = bp.target;
        AgentMap source_base = source_scaled;
        target.cloud = sparsified(bp.target.cloud, keep, 101);
        source_base.cloud = sparsified(source_scaled.cloud, keep, 202);
        // Cloud-only methods do not see the keyframes: once per (ratio, sparsity), on the first
        // variant only (the variants share their clouds).
        if (variant == sc.variants.front()) cloudOnlyRuns(source_base, target, expected, bp.extent, ratio, keep, rows);
        for (double roll : sc.rolls) {
          const AgentMap source = rolled(source_base, roll);
          const double t0 = nowMs();
          const MergeResult mr = mergeMaps(source, target, MergeRequest(), defaults);
          Row r = fromReport(mr.report, expected, bp.extent, nowMs() - t0);
          r.method = kOurs;
          r.variant = variant;
          r.ratio = ratio;
          r.roll = roll;
          r.sparsity = keep;
          rows.push_back(r);
          std::fprintf(stderr, "sweep %s ratio %g roll %g keep %g: %s %s (%.0f ms)\n", variant.c_str(), ratio, roll,
                       keep, r.status.c_str(), r.ok ? "success" : "miss", r.ms);
          Row nr = noScaleAblation(mr, source, target, expected, bp.extent);
          nr.variant = variant;
          nr.ratio = ratio;
          nr.roll = roll;
          nr.sparsity = keep;
          rows.push_back(nr);
        }
      }
    }
  }
  return rows;
}

// Success rate per method against each sweep dimension, and the error distribution.
void successTables(std::FILE* md, const SweepConfig& sc, const std::vector<Row>& rows, double target_extent) {

  std::fprintf(md, "Success = rotation < 1°, translation < 1 %% of the map extent (robust size of the target cloud, "
                   "%.2f m), scale < 1 %%, and the method reports success. Bundles: %zu variant(s) (`depth`: depth images; "
                   "`nodepth`: depth from the map cloud; `sharedworld`: depth images, clouds sampled from one world "
                   "cloud, see below). The source map is rescaled so that S_target_source has the given "
                   "scale; the source keyframe cameras are rolled about their optical axis (exact homography warp of "
                   "image and depth); both map clouds are randomly subsampled. Cloud-only methods run on the first "
                   "bundle's clouds (the maps are ≈110° apart) and do not depend on the roll.\n\n",
               target_extent, sc.variants.size());
  std::set<std::string> methods;
  std::vector<std::string> order;
  for (const Row& r : rows) {
    if (methods.insert(r.method).second) order.push_back(r.method);
  }
  // Cloud-only rows have no roll: leave them out of the roll table.
  auto table = [&](const char* title, const char* dim, const std::vector<double>& values,
                   const std::function<double(const Row&)>& key, const char* unit) {
    const bool by_roll = std::string(dim) == "roll";
    std::fprintf(md, "#### Success rate vs %s\n\n| method |", title);
    for (double v : values) std::fprintf(md, " %s = %g%s |", dim, v, unit);
    std::fprintf(md, " all |\n|---|");
    for (std::size_t i = 0; i <= values.size(); ++i) std::fprintf(md, "---|");
    std::fprintf(md, "\n");
    for (const std::string& m : order) {
      std::fprintf(md, "| %s |", m.c_str());
      int all_ok = 0, all_n = 0;
      bool any = false;
      for (double v : values) {
        int ok = 0, n = 0;
        for (const Row& r : rows) {
          if (r.method == m && key(r) == v && !(by_roll && r.variant == "clouds")) {
            ++n;
            ok += r.ok;
          }
        }
        all_ok += ok;
        all_n += n;
        any |= n > 0;
        std::fprintf(md, " %s |", n ? (pct(ok, n) + " (" + std::to_string(n) + ")").c_str() : "–");
      }
      std::fprintf(md, " %s |\n", any ? pct(all_ok, all_n).c_str() : "–");
    }
    std::fprintf(md, "\n");
  };
  table("scale ratio", "s", sc.ratios, [](const Row& r) { return r.ratio; }, "");
  table("keyframe roll (relative rotation between the keyframes)", "roll", sc.rolls,
        [](const Row& r) { return r.roll; }, "°");
  table("cloud sparsity (fraction of the map points kept)", "kept", sc.sparsities,
        [](const Row& r) { return r.sparsity; }, "");
  std::fprintf(md, "Cells are (successes / runs); `–` = not run for that method.\n\n");

  // Error distribution of the successful-or-not runs of ours and the baselines.
  std::fprintf(md, "#### Error distribution (all runs of each method)\n\n| method | runs | rotation median / 90 %% "
                   "[deg] | translation median / 90 %% [m] | scale median / 90 %% [%%] | time median [ms] |\n"
                   "|---|---|---|---|---|---|\n");
  for (const std::string& m : order) {
    std::vector<double> rot, tr, sc_, ms;
    for (const Row& r : rows) {
      if (r.method != m) continue;
      rot.push_back(r.err.rotation_deg);
      tr.push_back(r.err.translation);
      sc_.push_back(100 * r.err.scale_rel);
      ms.push_back(r.ms);
    }
    auto q = [](const std::vector<double>& v, int prec) {
      const double a = median(v), b = quantile(v, 0.9);
      auto f = [&](double x) { return x > 1e6 ? std::string("fail") : fmt(x, prec); };
      return f(a) + " / " + f(b);
    };
    std::fprintf(md, "| %s | %zu | %s | %s | %s | %.0f |\n", m.c_str(), rot.size(), q(rot, 2).c_str(), q(tr, 3).c_str(),
                 q(sc_, 2).c_str(), median(ms));
  }
  std::fprintf(md, "\nA run without a transform counts as `fail` (180°, infinite translation).\n\n");
}

  
// Cloud noise: Gaussian noise on every coordinate of both map clouds (σ = a fraction of each
// cloud's robust extent), full density, first variant, scale ratio 1 (the bundle's own 2.5),
// no roll; several noise draws per level.
void noiseTable(Output& out, std::FILE* md, const SweepConfig& sc, const BundlePair& bp) {
  const MergeOptions defaults;
  const BundleTruth& truth = bp.truth;
  const AgentMap& target_full = bp.target;
  const AgentMap& source_full = bp.source;
  const double extent = bp.extent;
  const double source_extent = robustExtent(source_full.cloud, 0.05).size;
  std::vector<Row> noise_rows;
  for (double level : sc.noise_levels) {
    for (int seed = 0; seed < sc.noise_seeds; ++seed) {
      std::mt19937 rng(303 + seed);
      std::normal_distribution<double> g(0.0, 1.0);
      AgentMap target = target_full, source = source_full;
      for (Eigen::Index i = 0; i < target.cloud.cols(); ++i) {
        target.cloud.col(i) += level * extent * Eigen::Vector3d(g(rng), g(rng), g(rng));
      }
      for (Eigen::Index i = 0; i < source.cloud.cols(); ++i) {
        source.cloud.col(i) += level * source_extent * Eigen::Vector3d(g(rng), g(rng), g(rng));
      }
      double t0 = nowMs();
      const MergeResult mr = mergeMaps(source, target, MergeRequest(), defaults);
      Row r = fromReport(mr.report, truth.target_source, extent, nowMs() - t0);
      r.method = kOurs;
      r.sparsity = level;  // the noise level, in this table
      noise_rows.push_back(r);
      RegistrationOptions reg = defaults.registration;
      reg.icp.estimate_scale = true;
      t0 = nowMs();
      Row c = fromReport(registerClouds(source.cloud, target.cloud, std::nullopt, reg), truth.target_source, extent,
                         nowMs() - t0);
      c.method = kNoKeyframe;
      c.sparsity = level;
      noise_rows.push_back(c);
      std::fprintf(stderr, "sweep noise %g seed %d: %s %s\n", level, seed, r.status.c_str(), r.ok ? "success" : "miss");
    }
  }
  std::fprintf(md, "#### Success rate vs cloud noise\n\nGaussian noise on every coordinate of both map clouds, σ "
                   "as a fraction of each cloud's extent (%.2f m for the target), full density, bundle `%s` at its "
                   "own scale ratio, no roll, %d noise draw(s) per level. Cells: successes / runs, median "
                   "translation error [m], median scale error [%%].\n\n| method |",
               extent, sc.variants.front().c_str(), sc.noise_seeds);
  for (double level : sc.noise_levels) std::fprintf(md, " σ = %g %% |", 100 * level);
  std::fprintf(md, "\n|---|");
  for (std::size_t i = 0; i < sc.noise_levels.size(); ++i) std::fprintf(md, "---|");
  std::fprintf(md, "\n");
  for (const char* m : {kOurs, kNoKeyframe}) {
    std::fprintf(md, "| %s |", m);
    for (double level : sc.noise_levels) {
      int ok = 0, n = 0;
      std::vector<double> tr, sc_;
      for (const Row& r : noise_rows) {
        if (r.method != m || r.sparsity != level) continue;
        ++n;
        ok += r.ok;
        tr.push_back(r.err.translation);
        sc_.push_back(100 * r.err.scale_rel);
      }
      const double mt = median(tr), ms = median(sc_);
      std::fprintf(md, " %d / %d; %s m; %s %% |", ok, n, mt > 1e6 ? "fail" : fmt(mt, 3).c_str(),
                   ms > 1e6 ? "fail" : fmt(ms, 2).c_str());
    }
    std::fprintf(md, "\n");
  }
  std::fprintf(md, "\n");
  std::FILE* ncsv = out.open("sweep_noise.csv");
  writeRows(ncsv, noise_rows);  // the sparsity column holds the noise level here
  std::fclose(ncsv);
}

// Outlier matches: the keyframe front end of mergeMaps, stage by stage on the keyframe pair
// it picks on the clean data, with wrong matches (random keypoint pairs) added to the SIFT
// matches so that they make the given fraction of all matches; then the similarity ICP from
// the resulting guess. Full density, first variant, the bundle's own scale ratio.
// One draw: `fraction` of wrong matches (random keypoint pairs) mixed into the clean matches.
Row outlierRun(const BundlePair& bp, const MapKeyframe& kf_s, const MapKeyframe& kf_t, const KeyframeFeatures& fs,
               const KeyframeFeatures& ft, const FeatureMatches& good, double fraction, int seed) {
  const MergeOptions defaults;
  const AgentMap& source = bp.source;
  const AgentMap& target = bp.target;
  std::mt19937 rng(404 + seed);
  std::uniform_int_distribution<std::size_t> pick_t(0, ft.keypoints.size() - 1), pick_s(0, fs.keypoints.size() - 1);
  const auto n_good = good.size();
  const auto n_bad = static_cast<std::size_t>(std::lround(fraction / (1.0 - fraction) * static_cast<double>(n_good)));
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> pixel_pairs;  // (target, source)
  for (std::size_t k = 0; k < n_good; ++k) pixel_pairs.emplace_back(good.pixels_a[k], good.pixels_b[k]);
  for (std::size_t k = 0; k < n_bad; ++k) {
    const cv::Point2f& pa = ft.keypoints[pick_t(rng)].pt;
    const cv::Point2f& pb = fs.keypoints[pick_s(rng)].pt;
    pixel_pairs.emplace_back(Eigen::Vector2d(pa.x, pa.y), Eigen::Vector2d(pb.x, pb.y));
  }
  std::shuffle(pixel_pairs.begin(), pixel_pairs.end(), rng);  // wrong matches not all at the end
  FeatureMatches mixed;
  for (const auto& [a, b] : pixel_pairs) {
    mixed.pixels_a.push_back(a);
    mixed.pixels_b.push_back(b);
  }
  const double t0 = nowMs();
  Row r;
  r.method = kOurs;
  r.sparsity = fraction;  // the outlier fraction, in this table
  FrontEndResult front;
  CandidatePair pair;
  pair.source = &kf_s;
  pair.target = &kf_t;
  pair.matches = mixed;
  pair.pose = keyframePairPose(mixed, target.camera, source.camera, defaults.relative_pose);
  front.verified = pair.pose.status == Status::kOk ? 1 : 0;
  front.pairs.push_back(pair);
  const KeyframeEstimate guess = front.verified ? SimilarityInitializer(defaults).run(source, target, front)
                                                : KeyframeEstimate();
  if (pair.pose.status != Status::kOk || guess.status != Status::kOk) {
    r.status = statusName(pair.pose.status != Status::kOk ? pair.pose.status : guess.status);
    r.err = Errors{180.0, 1e9, 1e9};
    r.ms = nowMs() - t0;
  } else {
    MapRegistration registration(defaults.registration, defaults.merge.refine_scale,
                                 defaults.merge.reweigh_keyframe_matches);
    registration.setClouds(source.cloud, target.cloud);
    const Refinement refined = registration.refine(guess.estimate, guess.matches);
    RegistrationReport rep;
    rep.status = refined.status;
    rep.message = refined.message;
    rep.transform = refined.estimate;
    r = fromReport(rep, bp.truth.target_source, bp.extent, nowMs() - t0);
    r.method = kOurs;
    r.sparsity = fraction;
  }
  return r;
}

void outlierTable(Output& out, std::FILE* md, const SweepConfig& sc, const BundlePair& bp) {
  const MergeOptions defaults;
  const AgentMap& source = bp.source;
  const AgentMap& target = bp.target;
  const MergeResult clean = mergeMaps(source, target, MergeRequest(), defaults);
  const MapKeyframe* kf_s = nullptr;
  const MapKeyframe* kf_t = nullptr;
  for (const MapKeyframe& k : source.keyframes) {
    if (clean.report.source_keyframe && k.id == *clean.report.source_keyframe) kf_s = &k;
  }
  for (const MapKeyframe& k : target.keyframes) {
    if (clean.report.target_keyframe && k.id == *clean.report.target_keyframe) kf_t = &k;
  }
  std::vector<Row> outlier_rows;
  std::size_t clean_matches = 0;
  if (kf_s && kf_t) {
    const KeyframeFeatures fs = extractFeatures(kf_s->image, defaults.matching);
    const KeyframeFeatures ft = extractFeatures(kf_t->image, defaults.matching);
    const FeatureMatches good = matchFeatures(ft, fs, defaults.matching);
    clean_matches = good.size();
    for (double fraction : sc.outlier_fractions) {
      for (int seed = 0; seed < sc.noise_seeds; ++seed) {
        const Row r = outlierRun(bp, *kf_s, *kf_t, fs, ft, good, fraction, seed);
        outlier_rows.push_back(r);
        std::fprintf(stderr, "sweep outliers %g seed %d: %s %s\n", fraction, seed, r.status.c_str(),
                     r.ok ? "success" : "miss");
      }
    }
  }
  std::fprintf(md, "#### Success rate vs outlier matches\n\nThe keyframe front end (relative pose RANSAC, "
                   "keyframe depth, Kalman-filter scale) run stage by stage on the keyframe pair picked on the "
                   "clean data (%zu SIFT matches), with random keypoint pairs added until they make the given "
                   "fraction of all matches, then the similarity ICP from the resulting guess (the merge gates are not applied). Bundle `%s`, full "
                   "density, %d draw(s) per fraction. Cells: successes / runs, median rotation [deg], translation "
                   "[m] and scale [%%] errors. A refusal is the expected outcome once the inlier ratio falls below "
                   "`relative_pose.min_inlier_ratio` (%.2f).\n\n| method |",
               clean_matches,
               sc.variants.front().c_str(), sc.noise_seeds, defaults.relative_pose.min_inlier_ratio);
  for (double f : sc.outlier_fractions) std::fprintf(md, " %g %% outliers |", 100 * f);
  std::fprintf(md, "\n|---|");
  for (std::size_t i = 0; i < sc.outlier_fractions.size(); ++i) std::fprintf(md, "---|");
  std::fprintf(md, "\n| %s |", kOurs);
  for (double f : sc.outlier_fractions) {
    int ok = 0, n = 0;
    std::vector<double> rot, tr, sc_;
    std::set<std::string> failed;
    for (const Row& r : outlier_rows) {
      if (r.sparsity != f) continue;
      ++n;
      ok += r.ok;
      if (r.status != "OK") failed.insert(r.status);
      rot.push_back(r.err.rotation_deg);
      tr.push_back(r.err.translation);
      sc_.push_back(100 * r.err.scale_rel);
    }
    const double mt = median(tr);
    std::string why;
    for (const std::string& st : failed) why += (why.empty() ? " (refused: " : ", ") + st;
    if (!why.empty()) why += ")";
    std::fprintf(md, " %d / %d%s; %s°; %s m; %s %% |", ok, n, why.c_str(),
                 mt > 1e6 ? "fail" : fmt(median(rot), 2).c_str(), mt > 1e6 ? "fail" : fmt(mt, 3).c_str(),
                 mt > 1e6 ? "fail" : fmt(median(sc_), 2).c_str());
  }
  std::fprintf(md, "\n\n");
  std::FILE* ocsv = out.open("sweep_outliers.csv");
  writeRows(ocsv, outlier_rows);  // the sparsity column holds the outlier fraction here
  std::fclose(ocsv);
}

// Ours per bundle and density: the real bundles' clouds carry their own frames' pose errors
// (pose.txt, ≈1° / a few cm), the shared-world bundle's clouds sample one world cloud.
void bundleTable(std::FILE* md, const SweepConfig& sc, const std::vector<Row>& rows) {
  std::fprintf(md, "#### pcr_pro success per bundle and cloud density\n\n| bundle |");
  for (double v : sc.sparsities) std::fprintf(md, " kept = %g |", v);
  std::fprintf(md, " median translation / scale error at each density |\n|---|");
  for (std::size_t i = 0; i <= sc.sparsities.size(); ++i) std::fprintf(md, "---|");
  std::fprintf(md, "\n");
  for (const std::string& variant : sc.variants) {
    std::fprintf(md, "| `%s` |", variant.c_str());
    std::string errs;
    for (double v : sc.sparsities) {
      int ok = 0, n = 0;
      std::vector<double> tr, sc_;
      for (const Row& r : rows) {
        if (r.method != kOurs || r.variant != variant || r.sparsity != v) continue;
        ++n;
        ok += r.ok;
        tr.push_back(r.err.translation);
        sc_.push_back(100 * r.err.scale_rel);
      }
      std::fprintf(md, " %s |", n ? (pct(ok, n) + " (" + std::to_string(n) + ")").c_str() : "–");
      const double mt = median(tr);
      errs += (errs.empty() ? "" : "; ") + (mt > 1e6 ? std::string("fail") : fmt(mt, 3) + " m / " + fmt(median(sc_), 2) + " %");
    }
    std::fprintf(md, " %s |\n", errs.c_str());
  }
  std::fprintf(md, "\n`depth`, `nodepth`: each agent's cloud is built from its own frames with their approximate "
                   "pose.txt poses, so the two clouds disagree by those pose errors and the truth (exact for the "
                   "keyframe poses) is only as good as ≈1° / a few cm for the clouds (compare the errors at full "
                   "density with the 1 %% thresholds). `sharedworld`: the same keyframes, "
                   "both clouds drawn from one world cloud (each point to an agent whose frames see it), so the truth "
                   "is exact for the clouds too.\n\n");
}

// Where ours applies: the map clouds keep at least kApplies of their points. At 10 % (~1.4k
// source points) the error on the shared-world bundle reaches ~1 % of the extent.
void sweepHeadline(std::FILE* md, std::FILE* headline, const SweepConfig& sc, const std::vector<Row>& rows,
                   long source_points) {
  std::vector<std::string> order;  // methods in order of appearance
  for (const Row& r : rows) {
    if (std::find(order.begin(), order.end(), r.method) == order.end()) order.push_back(r.method);
  }
  const double kApplies = 0.3;
  struct Tally {
    int ok = 0, n = 0, ok_all = 0, n_all = 0;
    std::map<std::string, std::pair<int, int>> by_status;
  };
  Tally exact, real;
  for (const Row& r : rows) {
    if (r.method != kOurs) continue;
    Tally& t = r.variant == "sharedworld" ? exact : real;
    ++t.n_all;
    t.ok_all += r.ok;
    if (r.sparsity >= kApplies - 1e-9) {
      ++t.n;
      t.ok += r.ok;
      auto& st = t.by_status[r.status];
      ++st.first;
      st.second += r.ok;
    }
  }
  auto report = [&](const char* what, const Tally& t) {
    std::fprintf(md, "**pcr_pro success where it applies, %s** (both map clouds keep ≥ %.0f %% of their points, i.e. "
                     "≥ ~%.0fk source points; every ratio and roll): **%s** (%d / %d). Over every density: %s "
                     "(%d / %d). Outcomes in the applicable cells:",
                 what, 100 * kApplies, 1e-3 * source_points * kApplies, pct(t.ok, t.n).c_str(), t.ok, t.n,
                 pct(t.ok_all, t.n_all).c_str(), t.ok_all, t.n_all);
    for (const auto& [status, c] : t.by_status) std::fprintf(md, " %s %d (%d successful);", status.c_str(), c.first, c.second);
    std::fprintf(md, "\n\n");
  };
  if (exact.n_all) report("truth exact for the clouds (`sharedworld`)", exact);
  if (real.n_all) report("real bundles with approximate truth (`depth`, `nodepth`)", real);
  std::fprintf(headline,
               "- Robustness sweep (scale ratio %g–%g, keyframe roll %g–%g°, clouds kept %g–%g %%), pcr_pro where it "
               "applies (≥ %.0f %% of the map points kept): ",
               sc.ratios.front(), sc.ratios.back(), sc.rolls.front(), sc.rolls.back(), 100 * sc.sparsities.back(),
               100 * sc.sparsities.front(), 100 * kApplies);
  if (exact.n) {
    std::fprintf(headline, "**%s** of %d merges on the bundle whose truth is exact for the clouds (`sharedworld`; "
                           "%s over all %d cells); ",
                 pct(exact.ok, exact.n).c_str(), exact.n, pct(exact.ok_all, exact.n_all).c_str(), exact.n_all);
  }
  if (real.n) {
    std::fprintf(headline, "%s of %d on the real bundles with approximate truth (`depth`, `nodepth`; %s over all %d "
                           "cells); ",
                 pct(real.ok, real.n).c_str(), real.n, pct(real.ok_all, real.n_all).c_str(), real.n_all);
  }
  std::fprintf(headline, "floor ≥ 99 %%: %s on the exact-truth bundle, %s on the real bundles.\n",
               exact.n ? (100.0 * exact.ok / exact.n >= 99.0 ? "met" : "NOT met") : "not run",
               real.n ? (100.0 * real.ok / real.n >= 99.0 ? "met" : "NOT met") : "not run");
  for (const std::string& m : order) {
    if (m == kOurs) continue;
    int mo = 0, mn = 0;
    for (const Row& r : rows) {
      if (r.method == m) {
        ++mn;
        mo += r.ok;
      }
    }
    std::fprintf(headline, "  - %s: %s of %d runs.\n", m.c_str(), pct(mo, mn).c_str(), mn);
  }
}

SweepConfig sweepConfig(bool quick) {
  SweepConfig sc;
  if (quick) {
    sc.ratios = {0.1, 10.0};
    sc.rolls = {0.0, 90.0};
    sc.sparsities = {1.0};
    sc.variants = {"depth", "sharedworld"};
    sc.noise_levels = {0.003};
    sc.outlier_fractions = {0.5};
  } else {
    // Reduced from the earlier sweep (7 ratios x 3 rolls x 4 densities): the real and simulated
    // cases now carry the accuracy claims; this keeps the extremes of each dimension.
    sc.ratios = {0.1, 1.0, 10.0};
    sc.rolls = {0.0, 90.0};
    sc.sparsities = {1.0, 0.3, 0.1};
    sc.variants = {"depth", "nodepth", "sharedworld"};
    sc.noise_levels = {0.0, 0.003, 0.01};
    sc.outlier_fractions = {0.0, 0.5, 0.7};
    sc.noise_seeds = 2;
  }
  return sc;
}

}  // namespace

void sectionSweep(Output& out, const SuiteConfig& config, std::FILE* headline) {
  const SweepConfig sc = sweepConfig(config.quick);
  const std::vector<Row> rows = sweepRuns(sc);
  std::FILE* csv = out.open("sweep.csv");
  writeRows(csv, rows);
  std::fclose(csv);
  const BundlePair first = loadBundlePair(sc.variants.front());
  std::FILE* md = out.open("sweep.md");
  successTables(md, sc, rows, first.extent);
  if (!sc.noise_levels.empty()) noiseTable(out, md, sc, first);
  if (!sc.outlier_fractions.empty()) outlierTable(out, md, sc, first);
  bundleTable(md, sc, rows);
  sweepHeadline(md, headline, sc, rows, static_cast<long>(first.source.cloud.cols()));
  std::fclose(md);
}

}  // namespace bench
}  // namespace pcr_pro
