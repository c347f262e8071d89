#include "pcr_pro/registration/icp.h"

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <numeric>
#include <random>
#include <string>
#include <vector>

#include "pcr_pro/geometry/median.h"
#include "pcr_pro/registration/filters.h"
#include "pcr_pro/geometry/kdtree.h"
#include "pcr_pro/geometry/normals.h"

namespace pcr_pro {
namespace {

struct Match {
  Eigen::Index source;
  Eigen::Index target;
  double d2;
  double weight = 1.0;  // IRLS weight (robust kernel)
};

// What the rejection needs besides the options: the trees, the pose and the spacings.
struct MatchContext {
  const KdTree& target;
  const KdTree* source = nullptr;  // tree of the level's source points (source frame), for the reciprocal check
  Sim3 pose;                       // current S_target_source
  double spacing = 0.0;            // max(target spacing, scaled source spacing) [target units]
};

// The fixed and adaptive distance gates and the trim, on candidate matches (target < 0: rejected).
std::vector<Match> gateMatches(const std::vector<Match>& all, const IcpOptions& o, double spacing) {
  std::vector<Match> kept;
  kept.reserve(all.size());
  const double max_d2 = o.max_correspondence_distance > 0.0
                            ? o.max_correspondence_distance * o.max_correspondence_distance
                            : std::numeric_limits<double>::infinity();
  for (const Match& m : all) {
    if (m.target >= 0 && m.source >= 0 && m.d2 <= max_d2) kept.push_back(m);
  }
  if (o.adaptive_distance_factor > 0.0 && !kept.empty()) {
    std::vector<double> d(kept.size());
    for (std::size_t k = 0; k < kept.size(); ++k) d[k] = std::sqrt(kept[k].d2);
    const double gate = o.adaptive_distance_factor * std::max(1.4826 * upperMedian(d), spacing);
    const double gate2 = gate * gate;
    kept.erase(std::remove_if(kept.begin(), kept.end(), [gate2](const Match& m) { return m.d2 > gate2; }), kept.end());
  }
  if (o.trim_ratio < 1.0 && !kept.empty()) {
    const auto keep_n = std::max<std::size_t>(
        1, static_cast<std::size_t>(std::ceil(o.trim_ratio * static_cast<double>(kept.size()))));
    if (keep_n < kept.size()) {
      std::nth_element(kept.begin(), kept.begin() + static_cast<std::ptrdiff_t>(keep_n - 1), kept.end(),
                       [](const Match& a, const Match& b) { return a.d2 < b.d2; });
      kept.resize(keep_n);
    }
  }
  return kept;
}

// Squared distance from each moved source point to its nearest target point [target units²], as
// the forward matching measured it; NaN where it did not (points outside a coarse level's
// subset). The reverse matching's reciprocal check asks the same question of the same moved
// points, and takes the answer from here instead of searching the target's tree again.
using NearestTargetD2 = std::vector<double>;

// Nearest neighbour of every transformed source point, then the overlap-aware checks
// (reciprocal, fixed and adaptive distance gates) and the trim. Dynamic chunks: a core busy with
// another process (SLAM runs beside us) then slows the loop down to one thread's speed instead of
// stalling it at the barrier. `*nearest_d2` (when given) receives every measured distance.
// `*hints` (when given, one per source point) holds each point's last nearest target point, which
// starts its search, and receives the new one.
std::vector<Match> matchAndReject(const Cloud& moved, const MatchContext& ctx, const IcpOptions& o,
                                  const std::vector<Eigen::Index>* subset = nullptr,
                                  NearestTargetD2* nearest_d2 = nullptr, std::vector<Eigen::Index>* hints = nullptr) {
  const Eigen::Index n = subset ? static_cast<Eigen::Index>(subset->size()) : moved.cols();
  std::vector<Match> all(static_cast<std::size_t>(n));
  const auto points = static_cast<std::size_t>(moved.cols());
  if (nearest_d2) nearest_d2->assign(points, std::numeric_limits<double>::quiet_NaN());
  if (hints && hints->size() != points) hints->assign(points, -1);
  const bool reciprocal = o.reciprocal && ctx.source != nullptr;
  const Sim3 inverse = ctx.pose.inverse();
  const double tolerance = o.reciprocal_tolerance * ctx.spacing;
#pragma omp parallel for schedule(dynamic, 256) if (n >= 1024)
  for (Eigen::Index k = 0; k < n; ++k) {
    const Eigen::Index i = subset ? (*subset)[static_cast<std::size_t>(k)] : k;
    double d2 = 0.0;
    const auto si = static_cast<std::size_t>(i);
    Eigen::Index j = ctx.target.nearest(moved.col(i), &d2, hints ? (*hints)[si] : -1);
    if (hints) (*hints)[si] = j;
    if (j >= 0 && nearest_d2) (*nearest_d2)[si] = d2;
    if (j >= 0 && reciprocal) {
      // Rejected when target j has a source point nearer than this one by more than the
      // tolerance: some source point closer to j than `reach` (target units). No source point
      // can be when this one is within the tolerance.
      const double reach = std::sqrt(d2) - tolerance;
      if (reach > 0.0) {
        const double reach_source = reach / ctx.pose.scale();
        if (ctx.source->anyCloserThan(inverse.apply(Eigen::Vector3d(ctx.target.points().col(j))),
                                      reach_source * reach_source)) {
          j = -1;
        }
      }
    }
    all[static_cast<std::size_t>(k)] = Match{i, j, d2, 1.0};
  }
  return gateMatches(all, o, ctx.spacing);
}

// Symmetric matching: the nearest moved source point of each of the given target points, with
// the same checks mirrored (the source point's own nearest target point must be about as close).
// A target point beyond the source's border pulls the source outwards as a source point beyond
// the target's border pulls it inwards: together the border pulls cancel. The source point's own
// nearest target distance comes from `forward` where the forward matching measured it. `*hints`
// (one per entry of `targets`) as in matchAndReject().
std::vector<Match> reverseMatchAndReject(const Cloud& moved, const MatchContext& ctx, const KdTree& source_tree,
                                         const std::vector<Eigen::Index>& targets, const IcpOptions& o,
                                         const NearestTargetD2& forward, std::vector<Eigen::Index>* hints) {
  const auto n = static_cast<Eigen::Index>(targets.size());
  std::vector<Match> all(targets.size());
  if (hints->size() != targets.size()) hints->assign(targets.size(), -1);
  const Sim3 inverse = ctx.pose.inverse();
  const double tolerance = o.reciprocal_tolerance * ctx.spacing;
  const Cloud& target = ctx.target.points();
#pragma omp parallel for schedule(dynamic, 256) if (n >= 1024)
  for (Eigen::Index k = 0; k < n; ++k) {
    const Eigen::Index j = targets[static_cast<std::size_t>(k)];
    double d2s = 0.0;
    const auto sk = static_cast<std::size_t>(k);
    Eigen::Index i = source_tree.nearest(inverse.apply(Eigen::Vector3d(target.col(j))), &d2s, (*hints)[sk]);
    (*hints)[sk] = i;
    const double d2 = d2s * ctx.pose.scale() * ctx.pose.scale();
    if (i >= 0 && o.reciprocal) {
      const auto si = static_cast<std::size_t>(i);
      double back2 = si < forward.size() ? forward[si] : std::numeric_limits<double>::quiet_NaN();
      if (std::isnan(back2)) ctx.target.nearest(moved.col(i), &back2);
      if (std::sqrt(d2) > std::sqrt(back2) + tolerance) i = -1;
    }
    all[static_cast<std::size_t>(k)] = Match{i, j, d2, 1.0};
  }
  return gateMatches(all, o, ctx.spacing);
}

// Point-to-plane correspondences of one iteration, forward (target normals) and reverse (the
// source points' normals, rotated into the target frame) together. Each residual is
// n·(moving - fixed): `moving` is in the moved source (the point, or for a reverse entry the
// plane's point), `fixed` in the target.
struct PlaneSet {
  std::vector<Eigen::Index> source, target;
  std::vector<Eigen::Vector3d> normal, moving, fixed;
  std::vector<char> reversed;  // the plane is the source's
  std::vector<double> weight, d2;
  // Local noise (IcpOptions::local_noise): each residual's relative precision u (the median
  // residual variance over its own) and the moving point's share φ of its variance; empty = off.
  std::vector<double> precision, phi;
  double spread = 0.0;
  std::size_t size() const { return source.size(); }
  double residual(std::size_t k) const { return normal[k].dot(moving[k] - fixed[k]); }
};

PlaneSet planeSet(const Cloud& moved, const Cloud& target, const std::vector<Match>& forward,
                  const Cloud& target_normals, const std::vector<Match>& reverse, const Cloud* source_normals,
                  const Eigen::Matrix3d& rotation) {
  PlaneSet p;
  auto add = [&](const Match& m, const Eigen::Vector3d& n, bool reversed) {
    p.source.push_back(m.source);
    p.target.push_back(m.target);
    p.normal.push_back(n);
    p.moving.push_back(moved.col(m.source));
    p.fixed.push_back(target.col(m.target));
    p.reversed.push_back(reversed ? 1 : 0);
    p.weight.push_back(1.0);
    p.d2.push_back(m.d2);
  };
  for (const Match& m : forward) add(m, target_normals.col(m.target), false);
  if (source_normals) {
    for (const Match& m : reverse) add(m, rotation * source_normals->col(m.source), true);
  }
  return p;
}

// Each plane's point moved to the centroid of the plane's neighbours (the target's for forward
// entries, the source's, moved by `current`, for reverse ones): the plane through a point's k
// neighbours carries a k-th of one point's noise along the normal.
void planesThroughCentroids(const Cloud& target_centroids, const Cloud* source_centroids, const Sim3& current,
                            PlaneSet* p) {
  for (std::size_t k = 0; k < p->size(); ++k) {
    if (p->reversed[k]) {
      if (source_centroids) p->moving[k] = current.apply(Eigen::Vector3d(source_centroids->col(p->source[k])));
    } else {
      p->fixed[k] = target_centroids.col(p->target[k]);
    }
  }
}

// A cloud's local thickness never counts as less than a tenth of its median over the
// correspondences: ten neighbours measure it to about ±50 %, and a few that happen to lie on one
// plane would otherwise take the fit over.
constexpr double kLocalThicknessFloor = 0.1;
// ... nor below the noise floor of the clouds' resolution (kNoiseFloorPerSpacing), so that
// noise-free clouds weigh their residuals alike.

// Local noise (IcpOptions::local_noise): each residual's variance from the thickness of the two
// clouds where it lies, t_p of the plane's neighbours and t_q of the point's (the moving side
// scaled by s²). The plane passes through the centroid of k neighbours, so it carries t_p / k:
// var = t_p / k + t_q, and the moving side's share φ of it (the scale's noise correction) is its
// part. Sets each residual's precision relative to the median variance (kernel and step weights).
void setLocalNoise(const Eigen::VectorXd& target_t2, const Eigen::VectorXd& source_t2, double scale, int k,
                   double spacing, PlaneSet* p) {
  const std::size_t n = p->size();
  if (n == 0) return;
  std::vector<double> tt(n), ts(n);
  for (std::size_t i = 0; i < n; ++i) {
    tt[i] = target_t2(p->target[i]);
    ts[i] = scale * scale * source_t2(p->source[i]);
  }
  const double resolution = std::pow(spacing / kNoiseFloorPerSpacing, 2);
  const double floor_t = std::max(kLocalThicknessFloor * upperMedian(tt), resolution);
  const double floor_s = std::max(kLocalThicknessFloor * upperMedian(ts), resolution);
  std::vector<double> var(n);
  p->phi.assign(n, 0.0);
  for (std::size_t i = 0; i < n; ++i) {
    const double a = std::max(tt[i], floor_t), b = std::max(ts[i], floor_s);
    const double moving = p->reversed[i] ? b / k : b;
    var[i] = p->reversed[i] ? a + b / k : a / k + b;
    p->phi[i] = var[i] > 0.0 ? moving / var[i] : 0.0;
  }
  const double typical = upperMedian(var);
  p->precision.assign(n, 1.0);
  if (!(typical > 0.0)) return;
  for (std::size_t i = 0; i < n; ++i) p->precision[i] = var[i] > 0.0 ? typical / var[i] : 1.0;
}

// The kernel's IRLS weights on a plane set (see applyKernel()).
void applyPlaneKernel(const IcpOptions& o, double spacing, PlaneSet* p) {
  if (p->size() == 0) return;
  std::vector<double> r(p->size());
  const bool local = !p->precision.empty();
  // With local noise the kernel sees each residual in units of its own spread.
  for (std::size_t k = 0; k < p->size(); ++k) r[k] = p->residual(k) * (local ? std::sqrt(p->precision[k]) : 1.0);
  const double center = upperMedian(r);
  std::vector<double> dev(r.size());
  for (std::size_t k = 0; k < r.size(); ++k) dev[k] = std::abs(r[k] - center);
  p->spread = std::max(1.4826 * upperMedian(dev), 0.01 * spacing);
  const bool kernel = o.robust_kernel != RobustKernel::kNone && p->spread > 0.0;
  if (!kernel && !local) return;
  const double c2 = std::pow(o.kernel_width * p->spread, 2);
  for (std::size_t k = 0; k < p->size(); ++k) {
    p->weight[k] = (local ? p->precision[k] : 1.0) / (kernel ? 1.0 + r[k] * r[k] / c2 : 1.0);
  }
}

// Residual of a correspondence for the kernel: signed point-to-plane distance, or the 3D
// distance divided by sqrt(3) (a per-coordinate scale) for point-to-point.
double residualOf(const Cloud& moved, const Cloud& target, const Cloud* normals, const Match& m) {
  const Eigen::Vector3d r = moved.col(m.source) - target.col(m.target);
  return normals ? normals->col(m.target).dot(r) : r.norm() / std::sqrt(3.0);
}

// IRLS weights of the kernel from the residuals' robust spread (1.4826 MAD), floored at a
// hundredth of the spacing so that noise-free data do not divide by zero. Returns the spread.
double applyKernel(const Cloud& moved, const Cloud& target, const Cloud* normals, const IcpOptions& o, double spacing,
                   std::vector<Match>* m) {
  if (m->empty()) return 0.0;
  std::vector<double> r(m->size());
  for (std::size_t k = 0; k < m->size(); ++k) r[k] = residualOf(moved, target, normals, (*m)[k]);
  const double center = normals ? upperMedian(r) : 0.0;
  std::vector<double> dev(r.size());
  for (std::size_t k = 0; k < r.size(); ++k) dev[k] = std::abs(r[k] - center);
  // Point-to-point distances hold the sampling offset between the clouds (about half a spacing)
  // besides the noise: the spread never falls below it there, or the kernel would weigh points
  // by how well two samplings happen to line up.
  const double spread = std::max(1.4826 * upperMedian(dev), (normals ? 0.01 : 0.5) * spacing);
  if (o.robust_kernel == RobustKernel::kNone || !(spread > 0.0)) return spread;
  const double c2 = std::pow(o.kernel_width * spread, 2);
  for (std::size_t k = 0; k < m->size(); ++k) (*m)[k].weight = 1.0 / (1.0 + r[k] * r[k] / c2);
  return spread;
}

// Pseudo-inverse solve of a symmetric positive semi-definite system: directions whose
// eigenvalue is not above the largest over `condition_threshold` are unobservable and get no
// update.
template <int N>
Eigen::Matrix<double, N, 1> solvePsd(const Eigen::Matrix<double, N, N>& h, const Eigen::Matrix<double, N, 1>& b,
                                     double condition_threshold) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, N, N>> eig(h);
  const auto& ev = eig.eigenvalues();
  const double max_ev = ev.cwiseAbs().maxCoeff();
  Eigen::Matrix<double, N, 1> x = Eigen::Matrix<double, N, 1>::Zero();
  if (!(max_ev > 0.0)) return x;
  for (int k = 0; k < N; ++k) {
    if (ev(k) * condition_threshold > max_ev) {
      const auto v = eig.eigenvectors().col(k);
      x += v * (v.dot(b) / ev(k));
    }
  }
  return x;
}

// The share of a residual's variance that is the moving point's own noise, for forward and
// reverse entries (see pointToPlaneStep()).
struct NoiseShare {
  double forward = 0.0, reverse = 0.0;
};

// One weighted point-to-plane Gauss-Newton step (residuals weighted by w / σ², σ the residual
// spread), linearised about the centroid c of the moving points, with the anchors. Returns the
// incremental similarity in the target frame.
//
// The scale's estimating equation is corrected for the moving points' own noise (errors in
// variables). A moving point's noise ε (times the scale) is in both its residual r and its
// lever arm n·(y - c), so even at the true pose Σ w r n·(y - c) has the expected value
// Σ w s²σ_y², and the plain Gauss-Newton fixed point shrinks the source: shrinking it shrinks
// its noise in the residuals. With φ the share of a residual's variance that is the moving
// point's noise (`phi`), that expectation is Σ φ w r², which is subtracted: the gradient of
// Σ w r² / var(r), whose expected value is least at the truth. Every plane passes through the
// centroid of its point's k neighbours, which carries a k-th of one point's noise along the
// normal, so φ = s²σ_s² / (s²σ_s² + σ_t²/k) for a source point against a target plane and
// (s²σ_s²/k) / (s²σ_s²/k + σ_t²) for a source plane against a target point. σ_s² and σ_t² are the
// clouds' surfaceThickness2() (same k, so their ratio compares the noise). On simulated
// semi-dense maps (60 % overlap, no drift) started at the truth, the scale ICP drifted -0.54 %
// at inverse-depth noise 0.01 and -4.0 % at 0.03 with no correction; -0.18 % and -1.1 % with
// planes through the matched points themselves and one φ for both directions; -0.11 % and
// -0.47 % now. A residual against the matched point keeps that point's whole noise, and the
// nearest point is chosen partly by its own noise, which a plane through k neighbours averages
// out.
Sim3 pointToPlaneStep(const PlaneSet& m, const std::vector<PointMatch3>* anchors, const Sim3& current,
                      bool with_scale, double max_log_scale_step, const NoiseShare& phi, double condition_threshold) {
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& y : m.moving) c += y;
  c /= static_cast<double>(m.size());
  Eigen::Matrix<double, 7, 7> h = Eigen::Matrix<double, 7, 7>::Zero();
  Eigen::Matrix<double, 7, 1> g = Eigen::Matrix<double, 7, 1>::Zero();
  const double inv_var = 1.0 / (m.spread * m.spread);
  for (std::size_t k = 0; k < m.size(); ++k) {
    const Eigen::Vector3d& n = m.normal[k];
    const Eigen::Vector3d a = m.moving[k] - c;
    Eigen::Matrix<double, 7, 1> j;
    j << n, a.cross(n), n.dot(a);
    const double r = m.residual(k);
    const double w = m.weight[k] * inv_var;
    h.noalias() += w * j * j.transpose();
    g.noalias() += w * j * r;
    const double share = m.phi.empty() ? (m.reversed[k] ? phi.reverse : phi.forward) : m.phi[k];
    g(6) -= share * w * r * r;
  }
  if (anchors) addAnchorNormalEquations(*anchors, current, c, &h, &g);
  // Rotation and log scale in units of the moving points' RMS radius ρ, as the covariance
  // measures the condition (E = diag(1, 1, 1, 1/ρ, ...): solve E H E u = -E g, step E u), so that
  // the directions this step leaves alone are the ones the covariance calls unobservable.
  double rho2 = 0.0;
  for (const Eigen::Vector3d& y : m.moving) rho2 += (y - c).squaredNorm();
  const double rho = rho2 > 0.0 ? std::sqrt(rho2 / static_cast<double>(m.size())) : 1.0;
  Eigen::Matrix<double, 7, 1> e;
  e << 1.0, 1.0, 1.0, 1.0 / rho, 1.0 / rho, 1.0 / rho, 1.0 / rho;
  const Eigen::Matrix<double, 7, 7> hu = e.asDiagonal() * h * e.asDiagonal();
  const Eigen::Matrix<double, 7, 1> gu = e.cwiseProduct(g);
  Eigen::Matrix<double, 7, 1> delta = Eigen::Matrix<double, 7, 1>::Zero();
  if (with_scale) {
    delta = solvePsd<7>(hu, -gu, condition_threshold);
  } else {
    delta.head<6>() = solvePsd<6>(hu.topLeftCorner<6, 6>(), -gu.head<6>(), condition_threshold);
  }
  delta = e.cwiseProduct(delta);
  const double ds = std::max(-max_log_scale_step, std::min(max_log_scale_step, delta(6)));
  const double s = std::exp(ds);
  const Eigen::Matrix3d r = expSO3(delta.segment<3>(3));
  return Sim3(s, r, c - s * (r * c) + delta.head<3>());
}

// One weighted point-to-point step (weighted Umeyama); anchors join as weighted point pairs with
// the weight of their covariance's mean variance against the residual spread.
Sim3 pointToPointStep(const Cloud& moved, const Cloud& target, const std::vector<Match>& m, double spread,
                      const std::vector<PointMatch3>* anchors, const Sim3& current, bool with_scale) {
  const std::size_t na = anchors ? anchors->size() : 0;
  const auto total = static_cast<Eigen::Index>(m.size() + na);
  Cloud y(3, total), q(3, total);
  Eigen::VectorXd w(total);
  for (std::size_t k = 0; k < m.size(); ++k) {
    const auto col = static_cast<Eigen::Index>(k);
    y.col(col) = moved.col(m[k].source);
    q.col(col) = target.col(m[k].target);
    w(col) = m[k].weight;
  }
  for (std::size_t k = 0; k < na; ++k) {
    const PointMatch3& a = (*anchors)[k];
    const auto col = static_cast<Eigen::Index>(m.size() + k);
    y.col(col) = current.apply(a.source);
    q.col(col) = a.target;
    const double var = a.covariance.trace() / 3.0;
    w(col) = var > 0.0 ? spread * spread / var : 0.0;
  }
  return umeyama(y, q, w, with_scale);
}

// Target normals estimated on demand: only target points that get matched ever need one.
class LazyNormals {
 public:
  LazyNormals(const KdTree& tree, int k)
      : tree_(tree),
        k_(k),
        normals_(Cloud::Zero(3, tree.size())),
        centroids_(tree.points()),
        thickness2_(Eigen::VectorXd::Zero(tree.size())),
        known_(static_cast<std::size_t>(tree.size()), 0) {}

  // Makes sure every matched target point has its normal.
  void ensure(const std::vector<Match>& matches) {
    std::vector<Eigen::Index> missing;
    for (const Match& m : matches) {
      char& known = known_[static_cast<std::size_t>(m.target)];
      if (!known) {
        known = 1;
        missing.push_back(m.target);
      }
    }
    fill(missing);
  }

  // Makes sure the given points have their normals.
  void ensureIndices(const std::vector<Eigen::Index>& indices) {
    std::vector<Eigen::Index> missing;
    for (Eigen::Index i : indices) {
      char& known = known_[static_cast<std::size_t>(i)];
      if (!known) {
        known = 1;
        missing.push_back(i);
      }
    }
    fill(missing);
  }

  const Cloud& normals() const { return normals_; }
  // Centroid of each known point's neighbours (the point itself where its normal is zero).
  const Cloud& centroids() const { return centroids_; }
  // Each known point's neighbours' variance along its normal (0 where unknown) [cloud units²].
  const Eigen::VectorXd& thickness2() const { return thickness2_; }

 private:
  void fill(const std::vector<Eigen::Index>& missing) {
    if (missing.empty()) return;
    Cloud centroids;
    Eigen::VectorXd thickness2;
    const Cloud fresh = estimateNormalsAt(tree_, missing, k_, &centroids, &thickness2);
    for (std::size_t i = 0; i < missing.size(); ++i) {
      normals_.col(missing[i]) = fresh.col(static_cast<Eigen::Index>(i));
      centroids_.col(missing[i]) = centroids.col(static_cast<Eigen::Index>(i));
      thickness2_(missing[i]) = thickness2(static_cast<Eigen::Index>(i));
    }
  }

  const KdTree& tree_;
  int k_;
  Cloud normals_;
  Cloud centroids_;
  Eigen::VectorXd thickness2_;
  std::vector<char> known_;
};

// setLocalNoise() on a plane set whose target planes come from `target` and source planes from
// `source` (the thickness of the points on the other side of each pair is estimated here).
void applyLocalNoise(LazyNormals& target, LazyNormals& source, double scale, int k, double spacing, PlaneSet* set) {
  std::vector<Eigen::Index> target_points, source_points;
  for (std::size_t i = 0; i < set->size(); ++i) {
    if (set->reversed[i]) {
      target_points.push_back(set->target[i]);
    } else {
      source_points.push_back(set->source[i]);
    }
  }
  target.ensureIndices(target_points);
  source.ensureIndices(source_points);
  setLocalNoise(target.thickness2(), source.thickness2(), scale, k, spacing, set);
}

}  // namespace

const char* errorMetricName(ErrorMetric metric) {
  return metric == ErrorMetric::kPointToPoint ? "point_to_point" : "point_to_plane";
}

const char* robustKernelName(RobustKernel kernel) { return kernel == RobustKernel::kNone ? "none" : "cauchy"; }

bool parseRobustKernel(const std::string& name, RobustKernel* kernel) {
  if (name == "none") {
    *kernel = RobustKernel::kNone;
    return true;
  }
  if (name == "cauchy") {
    *kernel = RobustKernel::kCauchy;
    return true;
  }
  return false;
}

bool parseErrorMetric(const std::string& name, ErrorMetric* metric) {
  if (name == "point_to_point") {
    *metric = ErrorMetric::kPointToPoint;
    return true;
  }
  if (name == "point_to_plane") {
    *metric = ErrorMetric::kPointToPlane;
    return true;
  }
  return false;
}

template <>
const ParamSchema<IcpOptions>& paramSchema<IcpOptions>() {
  using O = IcpOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"icp", {
      {"sampling.max_source_points", &O::max_source_points, R::atLeast(0), "points",
       "source randomly subsampled to at most this many points (with whole_source: the points that move); 0 = all"},
      {"sampling.whole_source", &O::whole_source, R::any(), "",
       "the source's k-d tree, planes, spacing, thickness and reciprocal check use the whole source cloud, as "
       "the target's do; max_source_points then only limits the points that move (more accurate on sparse noisy "
       "maps, slower on dense ones)"},
      {"sampling.coarse_source_points", &O::coarse_source_points, R::atLeast(0), "points",
       "coarse-to-fine: iterate first on this many source points, then 4x as many, ... (10x looser stop check, scale "
       "kept), then on the whole sample; 0 = one level"},
      {"sampling.register_noisier_as_target", &O::register_noisier_as_target, R::any(), "",
       "when the source's surface thickness (a variance, in target units) is at least twice the target's, the "
       "target is registered onto the source and the result and its covariance inverted (registerClouds, the "
       "merge's refinement)"},
      {"matcher.normal_neighbors", &O::normal_neighbors, R::atLeast(3), "",
       "neighbours of each plane: its normal and the centroid it passes through"},
      {"outlier_rejection.max_correspondence_distance", &O::max_correspondence_distance, R::atLeast(0), "target units",
       "pairs farther apart are rejected; 0 = no fixed limit"},
      {"outlier_rejection.reciprocal", &O::reciprocal, R::any(), "",
       "keep source i -> target j only when i is about as close to j as j's nearest source point (drops points "
       "beyond the other cloud's border)"},
      {"outlier_rejection.symmetric", &O::symmetric, R::any(), "",
       "match target samples to the source too, so that the border pulls of a partial overlap cancel"},
      {"outlier_rejection.reciprocal_tolerance", &O::reciprocal_tolerance, R::atLeast(0), "point spacings",
       "slack of the reciprocal check"},
      {"outlier_rejection.adaptive_distance_factor", &O::adaptive_distance_factor, R::atLeast(0),
       "robust distance scales", "reject pairs farther than this many robust distance scales; 0 = off"},
      {"outlier_rejection.trim_ratio", &O::trim_ratio, R::openClosed(0, 1), "-",
       "fraction of the closest pairs kept; 1 = no trimming"},
      {"outlier_rejection.robust_kernel",
       TextParam<O>{+[](const O& o) { return std::string(robustKernelName(o.robust_kernel)); },
                    +[](O* o, const std::string& s) { return parseRobustKernel(s, &o->robust_kernel); },
                    "none or cauchy"},
       R::any(), "", "IRLS weights from the residuals' robust spread (1.4826 MAD)"},
      {"outlier_rejection.kernel_width", &O::kernel_width, R::above(0), "robust spreads", "Cauchy kernel width"},
      {"outlier_rejection.min_correspondences", &O::min_correspondences, R::atLeast(3), "",
       "fewer pairs fail the registration"},
      {"error_minimizer.type",
       TextParam<O>{+[](const O& o) { return std::string(errorMetricName(o.error_metric)); },
                    +[](O* o, const std::string& s) { return parseErrorMetric(s, &o->error_metric); },
                    "point_to_point or point_to_plane"},
       R::any(), "", "error metric"},
      {"error_minimizer.estimate_scale", &O::estimate_scale, R::any(), "",
       "estimate a similarity (scale) too, corrected for the source's noise (point_to_plane); pcr_pro_icp "
       "--estimate-scale sets it"},
      {"error_minimizer.local_noise", &O::local_noise, R::any(), "",
       "point_to_plane with symmetric matching: weigh each residual by its own noise, from both clouds' surface "
       "thickness where it lies, instead of one spread for all"},
      {"error_minimizer.max_scale_step", &O::max_scale_step, R::open(0, 1), "-",
       "largest relative scale change per iteration"},
      {"error_minimizer.min_scale_ratio", &O::min_scale_ratio, R::openClosed(0, 1), "-",
       "scale kept >= this times the initial scale"},
      {"error_minimizer.max_scale_ratio", &O::max_scale_ratio, R::atLeast(1), "-",
       "scale kept <= this times the initial scale"},
      {"error_minimizer.degeneracy_condition_threshold", &O::degeneracy_condition_threshold, R::above(1), "-",
       "point_to_plane: directions of a step whose information is below the largest over this (rotation and "
       "scale in units of the cloud radius) are unobservable and keep their initial value"},
      {"error_minimizer.extrapolation", &O::extrapolation, R::any(), "",
       "when successive steps point the same way and shrink, jump ahead by the rest of their geometric series "
       "(Besl & McKay's acceleration)"},
      {"stop.max_iterations", &O::max_iterations, R::atLeast(1), "", "counter check"},
      {"stop.min_relative_translation_change", &O::min_relative_translation_change, R::atLeast(0),
       "target RMS radius", "differential check"},
      {"stop.min_rotation_change", &O::min_rotation_change, R::atLeast(0), "rad", "differential check"},
      {"stop.min_scale_change", &O::min_scale_change, R::atLeast(0), "-", "differential check (relative)"},
  }};
  return schema;
}

void validate(const IcpOptions& o) {
  checkRanges(paramSchema<IcpOptions>(), o);
}

Sim3 umeyama(const Cloud& src, const Cloud& dst, bool with_scale) {
  return umeyama(src, dst, Eigen::VectorXd::Ones(src.cols()), with_scale);
}

Sim3 umeyama(const Cloud& src, const Cloud& dst, const Eigen::VectorXd& weights, bool with_scale) {
  const double total = weights.sum();
  if (!(total > 0.0)) return Sim3();
  const Eigen::Vector3d mu_s = src * weights / total;
  const Eigen::Vector3d mu_d = dst * weights / total;
  const Cloud cs = src.colwise() - mu_s;
  const Cloud cd = dst.colwise() - mu_d;
  const Eigen::Matrix3d sigma = cd * weights.asDiagonal() * cs.transpose() / total;
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(sigma, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Vector3d d = Eigen::Vector3d::Ones();
  if (svd.matrixU().determinant() * svd.matrixV().determinant() < 0) d(2) = -1;
  const Eigen::Matrix3d r = svd.matrixU() * d.asDiagonal() * svd.matrixV().transpose();
  double s = 1.0;
  if (with_scale) {
    const double var_s = (cs.colwise().squaredNorm().transpose().cwiseProduct(weights)).sum() / total;
    if (var_s > 0.0) s = svd.singularValues().dot(d) / var_s;
  }
  return Sim3(s, r, mu_d - s * (r * mu_s));
}

double medianSpacing(const KdTree& tree) {
  const Cloud& pts = tree.points();
  const Eigen::Index n = pts.cols();
  if (n < 2) return 0.0;
  const Eigen::Index step = std::max<Eigen::Index>(1, n / 2000);
  std::vector<double> d;
  std::vector<Eigen::Index> idx;
  std::vector<double> d2;
  for (Eigen::Index i = 0; i < n; i += step) {
    tree.knn(pts.col(i), 2, &idx, &d2);
    if (d2.size() == 2) d.push_back(std::sqrt(d2[1]));
  }
  return upperMedian(d);
}

namespace {

// Where one level of iterations ended.
struct LevelOutcome {
  bool failed = false;     // too few correspondences or a numerical failure; message set
  bool converged = false;  // the differential check passed
  int iterations = 0;
  int extrapolations = 0;
  std::string message;
};

// What every level of iterations shares.
struct LevelEnv {
  const KdTree& tree;
  LazyNormals& normals;
  const IcpOptions& o;
  double target_radius = 0.0;
  double target_spacing = 0.0;
  double min_scale = 0.0, max_scale = 0.0;
  const std::vector<PointMatch3>* anchors = nullptr;
  double target_thickness2 = 0.0;  // surfaceThickness2() of the target [target units²]
};

// Indices of about `count` target points spread evenly over the cloud (symmetric matching).
std::vector<Eigen::Index> targetSample(Eigen::Index size, Eigen::Index count) {
  std::vector<Eigen::Index> out;
  const double step = count > 0 ? std::max(1.0, static_cast<double>(size) / static_cast<double>(count)) : 1.0;
  for (double x = 0.0; x < static_cast<double>(size); x += step) out.push_back(static_cast<Eigen::Index>(x));
  return out;
}

// The source points in a tree (the reciprocal check and symmetric matching need it), their
// normals, spacing and thickness: built once and shared by every level, which differ only in
// which source points they move (a coarse level moves a subset: the same correspondences the
// whole sample has, fewer of them); and a sample of the target of the level's size (symmetric
// matching), set per level. The hints are the last iteration's nearest neighbours, which start
// the next iteration's searches (the points move little): one per source point (its nearest target
// point), one per entry of reverse_targets (its nearest source point).
struct LevelSource {
  std::unique_ptr<KdTree> tree;
  std::unique_ptr<LazyNormals> normals;
  std::vector<Eigen::Index> reverse_targets;
  std::vector<Eigen::Index> forward_hints, reverse_hints;
  double spacing = 0.0;
  double thickness2 = 0.0;  // surfaceThickness2() of the level's source [source units²]
};

LevelSource levelSource(const Cloud& source, const LevelEnv& env) {
  const IcpOptions& o = env.o;
  const bool plane = o.error_metric == ErrorMetric::kPointToPlane;
  const bool symmetric = o.symmetric && plane;
  LevelSource level;
  if (o.reciprocal || symmetric || (plane && o.estimate_scale)) {
    level.tree = std::make_unique<KdTree>(source);
    level.spacing = medianSpacing(*level.tree);
  }
  if (plane && o.estimate_scale) level.thickness2 = surfaceThickness2(*level.tree, o.normal_neighbors, kThicknessSamples);
  if (symmetric) level.normals = std::make_unique<LazyNormals>(*level.tree, o.normal_neighbors);
  return level;
}

// Seed of the coarse levels' subsets of the source points (equal inputs give equal results).
constexpr unsigned kCoarseSeed = 42;

// One minimisation step from the matches `*m` (weighted in place by the robust kernel):
// point-to-point with its log-scale step clamped, or point-to-plane (symmetric when configured).
Sim3 levelStep(const Cloud& moved, const MatchContext& ctx, const LevelEnv& env, const LevelSource& level,
               double max_log_step, const Sim3& current, const NearestTargetD2& nearest_d2,
               std::vector<Eigen::Index>* reverse_hints, std::vector<Match>* m_io) {
  const IcpOptions& o = env.o;
  const Cloud& target = env.tree.points();
  std::vector<Match>& m = *m_io;
  const bool plane = o.error_metric == ErrorMetric::kPointToPlane;
  const bool symmetric = o.symmetric && plane;
  Sim3 step;
  if (o.error_metric == ErrorMetric::kPointToPoint) {
    const double spread = applyKernel(moved, target, nullptr, o, ctx.spacing, &m);
    step = pointToPointStep(moved, target, m, spread, env.anchors, current, o.estimate_scale);
    const double ds = std::max(-max_log_step, std::min(max_log_step, std::log(step.scale())));
    if (std::exp(ds) != step.scale()) {
      // Scale clamped: keep the moved centroid where the step put it.
      const double sc = std::exp(ds);
      const Eigen::Vector3d mc = moved.rowwise().mean();
      step = Sim3(sc, step.rotation(), step.apply(mc) - sc * (step.rotation() * mc));
    }
  } else {
    env.normals.ensure(m);
    std::vector<Match> reverse;
    if (symmetric) {
      reverse = reverseMatchAndReject(moved, ctx, *level.tree, level.reverse_targets, o, nearest_d2, reverse_hints);
      std::vector<Eigen::Index> used;
      for (const Match& r : reverse) used.push_back(r.source);
      level.normals->ensureIndices(used);
    }
    PlaneSet set = planeSet(moved, target, m, env.normals.normals(), reverse,
                            symmetric ? &level.normals->normals() : nullptr, current.rotation());
    // Planes through the neighbours' centroids; the moving point's share of a residual's
    // variance: the source point's own noise against a target plane that carries a k-th of
    // the target's (forward), a source plane with a k-th of the source's against a whole
    // target point (reverse).
    planesThroughCentroids(env.normals.centroids(), symmetric ? &level.normals->centroids() : nullptr, current, &set);
    const double source2 = current.scale() * current.scale() * level.thickness2;
    const double target2 = env.target_thickness2;
    const double k = o.normal_neighbors;
    NoiseShare phi;
    if (source2 > 0.0) {
      phi.forward = source2 / (source2 + target2 / k);
      phi.reverse = (source2 / k) / (source2 / k + target2);
    }
    if (o.local_noise && symmetric) {
      applyLocalNoise(env.normals, *level.normals, current.scale(), o.normal_neighbors, ctx.spacing, &set);
    }
    applyPlaneKernel(o, ctx.spacing, &set);
    step = pointToPlaneStep(set, env.anchors, current, o.estimate_scale, max_log_step, phi,
                            o.degeneracy_condition_threshold);
  }
  return step;
}

// `t` with its scale clamped to [min_scale, max_scale], keeping the source centroid where `t`
// puts it; `t` itself when its scale is within (or not comparable).
Sim3 clampScale(const Sim3& t, double min_scale, double max_scale, const Eigen::Vector3d& source_centroid) {
  if (!(t.scale() < min_scale || t.scale() > max_scale)) return t;
  const double s = std::min(max_scale, std::max(min_scale, t.scale()));
  const Eigen::Vector3d at = t.apply(source_centroid);
  return Sim3(s, t.rotation(), at - s * (t.rotation() * source_centroid));
}

using Twist = Eigen::Matrix<double, 7, 1>;

// Extrapolation: ICP creeps along shallow valleys with steps that shrink by a nearly
// constant ratio r in a nearly constant direction; then the rest of that geometric series,
// r / (1 - r) times the last step, is taken at once (capped). A wrong guess costs one
// iteration: the next step points back, and no extrapolation follows a reversal.
// `aa` is the step's rotation, `mc` the moved centroid before it and `moved_by` how far the step
// moved it. @return whether *current jumped
bool extrapolate(const Sim3& step, const Eigen::AngleAxisd& aa, const Eigen::Vector3d& mc,
                 const Eigen::Vector3d& moved_by, const Twist& previous_twist, const Twist& twist, const LevelEnv& env,
                 const Eigen::Vector3d& source_centroid, Sim3* current) {
  const double n0 = previous_twist.norm(), n1 = twist.norm();
  const double cosine = n0 > 0.0 && n1 > 0.0 ? previous_twist.dot(twist) / (n0 * n1) : 0.0;
  const double r = n0 > 0.0 ? n1 / n0 : 1.0;
  if (cosine > kExtrapolationMinCosine && r < 1.0) {
    const double f = std::min(kExtrapolationMaxFactor, r / (1.0 - r));
    const double s = std::exp(f * std::log(step.scale()));
    const Eigen::Matrix3d rot = expSO3(f * aa.angle() * aa.axis());
    const Eigen::Vector3d c = step.apply(mc);  // the moved centroid after this step
    Sim3 extra(s, rot, c - s * (rot * c) + f * moved_by);
    Sim3 jumped = extra * *current;
    if (jumped.matrix().allFinite()) {
      *current = clampScale(jumped, env.min_scale, env.max_scale, source_centroid);
      return true;
    }
  }
  return false;
}

// Iterates match / reject / weight / minimise on `source` (its points in `subset` only, when
// given) from `*current` until the differential check passes at `tolerance` times the configured
// thresholds, or the iteration limit. `level` indexes the whole of `source`.
LevelOutcome iterateLevel(const Cloud& source, const LevelEnv& env, double tolerance, int iteration_offset,
                          LevelSource& level, const std::vector<Eigen::Index>* subset, Sim3* current) {
  const IcpOptions& o = env.o;
  LevelOutcome out;
  const double max_log_step = std::log1p(o.max_scale_step);
  const Eigen::Vector3d source_centroid = source.rowwise().mean();
  const double target_radius = env.target_radius;
  const auto moving = static_cast<Eigen::Index>(subset ? subset->size() : source.cols());
  if (level.normals) {
    level.reverse_targets = targetSample(env.tree.points().cols(), moving);
    level.reverse_hints.assign(level.reverse_targets.size(), -1);
  }
  Twist previous_twist = Twist::Zero();
  bool has_previous = false, extrapolated = false;
  for (; out.iterations < o.max_iterations; ++out.iterations) {
    const int iter = iteration_offset + out.iterations;
    const Cloud moved = current->apply(source);
    const MatchContext ctx{env.tree, level.tree.get(), *current,
                           std::max(env.target_spacing, level.spacing * current->scale())};
    NearestTargetD2 nearest_d2;
    std::vector<Match> m = matchAndReject(moved, ctx, o, subset, &nearest_d2, &level.forward_hints);
    if (static_cast<int>(m.size()) < o.min_correspondences) {
      out.failed = true;
      out.message = "icp: only " + std::to_string(m.size()) + " correspondences at iteration " + std::to_string(iter) +
                    " (need " + std::to_string(o.min_correspondences) + ")";
      return out;
    }
    const Sim3 step = levelStep(moved, ctx, env, level, max_log_step, *current, nearest_d2, &level.reverse_hints, &m);
    Sim3 next = step * *current;
    if (!next.matrix().allFinite()) {
      out.failed = true;
      out.message = "icp: numerical failure at iteration " + std::to_string(iter);
      return out;
    }
    next = clampScale(next, env.min_scale, env.max_scale, source_centroid);
    // Differential check on how far the step moved the source centroid, rotated and scaled.
    const Eigen::Vector3d mc = moved.rowwise().mean();
    const Eigen::Vector3d moved_by = step.apply(mc) - mc;
    const double dt = moved_by.norm();
    const double dr = step.rotationAngle();
    const double dsc = std::abs(next.scale() / current->scale() - 1.0);
    // The step as a 7-vector of displacements about the moved centroid (translation, rotation
    // and log scale times the target radius), for the extrapolation below.
    Twist twist;
    const Eigen::AngleAxisd aa(step.rotation());
    twist << moved_by, aa.angle() * aa.axis() * target_radius, std::log(step.scale()) * target_radius;
    *current = next;
    if (dt <= tolerance * o.min_relative_translation_change * target_radius &&
        dr <= tolerance * o.min_rotation_change && dsc <= tolerance * o.min_scale_change && !extrapolated) {
      out.converged = true;
      ++out.iterations;
      return out;
    }
    extrapolated = false;
    if (o.extrapolation && has_previous) {
      extrapolated = extrapolate(step, aa, mc, moved_by, previous_twist, twist, env, source_centroid, current);
      if (extrapolated) ++out.extrapolations;
    }
    previous_twist = twist;
    has_previous = !extrapolated;  // the step after a jump starts a new series
  }
  return out;
}

}  // namespace

IcpResult alignIcp(const Cloud& source, const Cloud& target, const Sim3& initial, const IcpOptions& o) {
  validate(o);
  if (source.cols() == 0) throw InputError("icp: source cloud is empty");
  if (target.cols() == 0) throw InputError("icp: target cloud is empty");
  const KdTree tree(target);
  return alignIcp(source, tree, initial, o);
}

namespace {

// Coarse levels: most of the travel from the initial guess on small samples (coarse_source_points,
// then four times as many, ...), each to a looser differential check; the whole sample then
// only has to settle the last digits. @return the iterations they took
int iterateCoarseLevels(const Cloud& source, const std::vector<Eigen::Index>* sample, const LevelEnv& env,
                        const IcpOptions& o, LevelSource& level, Sim3* current) {
  int iter = 0;
  // The coarse levels keep the scale (the whole sample estimates it). They move a random subset
  // of the source points against the whole source's tree, normals and spacing: the same
  // correspondences as the whole sample, fewer of them. A coarse level that was a sparser cloud
  // of its own (its own spacing, normals and reciprocal check) had other correspondences and
  // another optimum: from the exact truth, on the bench's simulated semi-dense maps of 15 %
  // overlap, it moved the estimate 4-5 deg away, into a minimum the whole sample then kept.
  IcpOptions rigid = o;
  rigid.estimate_scale = false;
  const LevelEnv rigid_env{env.tree,      env.normals, rigid,        env.target_radius, env.target_spacing,
                           env.min_scale, env.max_scale, env.anchors, env.target_thickness2};
  const Eigen::Index sample_size = sample ? static_cast<Eigen::Index>(sample->size()) : source.cols();
  if (o.coarse_source_points > 0 && 2 * static_cast<Eigen::Index>(o.coarse_source_points) < sample_size) {
    std::vector<Eigen::Index> order(static_cast<std::size_t>(sample_size));
    std::iota(order.begin(), order.end(), Eigen::Index{0});
    std::mt19937 rng(kCoarseSeed);
    std::shuffle(order.begin(), order.end(), rng);
    if (sample) {
      for (Eigen::Index& i : order) i = (*sample)[static_cast<std::size_t>(i)];
    }
    for (Eigen::Index n = o.coarse_source_points; 2 * n < sample_size; n *= 4) {
      std::vector<Eigen::Index> subset(order.begin(), order.begin() + n);
      std::sort(subset.begin(), subset.end());
      const LevelOutcome c = iterateLevel(source, rigid_env, kCoarseToleranceFactor, iter, level, &subset, current);
      iter += c.iterations;
      // A failed coarse level (e.g. too few correspondences on a small sample) leaves the
      // decision to the larger samples, from the last good pose.
    }
  }
  return iter;
}

// The final pairs as the covariance takes them: source point, target point, target normal and
// weight per pair. @return the sum of their squared distances
double fillMatches(const PlaneSet& set, const Cloud& source, const Cloud& target, Correspondences* c) {
  const auto count = static_cast<Eigen::Index>(set.size());
  c->source.resize(3, count);
  c->target.resize(3, count);
  c->target_normals.resize(3, count);
  c->weights.resize(count);
  double sum_d2 = 0.0;
  for (std::size_t k = 0; k < set.size(); ++k) {
    const auto col = static_cast<Eigen::Index>(k);
    c->source.col(col) = source.col(set.source[k]);
    c->target.col(col) = target.col(set.target[k]);
    c->target_normals.col(col) = set.normal[k];
    c->weights(col) = set.weight[k];
    sum_d2 += set.d2[k];
  }
  return sum_d2;
}

// How many times the final pairs count the same error [-], >= 1: the ratio of the variance of
// their weighted residual sum to the variance the closed form assumes for independent pairs.
// Pairs that share a point (a target point nearest to two source points, a pair found in both
// directions of symmetric matching) share that point's noise, so their residuals are correlated.
// Measured, not assumed: with r_c the residual and w_c the weight of pair c, and S_k the sum of
// w_c r_c over the pairs that use point k (normals turned to agree with the point's first pair),
// Var(Σ w r) ≈ Σ w² r² + Σ_k (S_k² − Σ_{c∋k} w_c² r_c²). The second sum is the residuals' products
// across pairs that share a point: what is common to both (the point's noise, or the same pair
// twice) adds up, what differs between them (sampling of a curved surface) averages out. One-to-one
// pairs give 1; every pair found in both directions gives 2; nearest-neighbour matching of two
// equally dense noisy samples, where some points serve several pairs, about 2.6.
double designEffect(const PlaneSet& set, const Cloud& moved, const Cloud& target, bool plane) {
  // Point-to-plane: residuals along the normal (turned to agree with the point's first pair);
  // point-to-point: the 3D residual vectors.
  struct PointSum {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    double sum_sq = 0.0;
    Eigen::Vector3d normal = Eigen::Vector3d::Zero();
  };
  std::vector<PointSum> by_source(static_cast<std::size_t>(moved.cols()));
  std::vector<PointSum> by_target(static_cast<std::size_t>(target.cols()));
  double independent = 0.0;
  auto add = [](PointSum* p, const Eigen::Vector3d& n, const Eigen::Vector3d& wr) {
    if (p->normal.isZero()) p->normal = n;
    p->sum += p->normal.dot(n) < 0.0 ? -wr : wr;
    p->sum_sq += wr.squaredNorm();
  };
  for (std::size_t k = 0; k < set.size(); ++k) {
    const Eigen::Vector3d& n = set.normal[k];
    const Eigen::Vector3d r = moved.col(set.source[k]) - target.col(set.target[k]);
    const Eigen::Vector3d wr = set.weight[k] * (plane ? Eigen::Vector3d(n.dot(r), 0.0, 0.0) : r);
    independent += wr.squaredNorm();
    add(&by_source[static_cast<std::size_t>(set.source[k])], plane ? n : Eigen::Vector3d::UnitX(), wr);
    add(&by_target[static_cast<std::size_t>(set.target[k])], plane ? n : Eigen::Vector3d::UnitX(), wr);
  }
  double shared = 0.0;
  for (const auto* points : {&by_source, &by_target}) {
    for (const PointSum& p : *points) shared += p.sum.squaredNorm() - p.sum_sq;
  }
  return independent > 0.0 ? std::max(1.0, (independent + shared) / independent) : 1.0;
}

// The status at the final pose: enough correspondences and converged, or why not.
void setFinalStatus(std::size_t correspondences, bool converged, int iterations, const IcpOptions& o,
                    IcpResult* result) {
  if (static_cast<int>(correspondences) < o.min_correspondences) {
    result->status = Status::kIcpNotConverged;
    result->message = "icp: too few correspondences at the final pose";
  } else if (!converged) {
    result->status = Status::kIcpNotConverged;
    result->message = "icp: no convergence within " + std::to_string(o.max_iterations) + " iterations on the full sample";
  } else {
    result->status = Status::kOk;
    result->message = "icp converged in " + std::to_string(iterations) + " iterations";
  }
}

}  // namespace

IcpResult alignIcp(const Cloud& source_in, const KdTree& tree, const Sim3& initial, const IcpOptions& o,
                   const std::vector<PointMatch3>* anchors) {
  validate(o);
  if (source_in.cols() == 0) throw InputError("icp: source cloud is empty");
  MaxPointsOptions sampling;
  sampling.max_points = o.max_source_points;
  // The points that move: the sample itself, or (whole_source) the sample's columns of the whole
  // source, which then also makes the source's side of the matching.
  const Cloud sampled = o.whole_source ? Cloud() : maxPointsFilter(source_in, sampling);
  const Cloud& source = o.whole_source ? source_in : sampled;
  const std::vector<Eigen::Index> sample_indices =
      o.whole_source ? maxPointsIndices(source_in.cols(), sampling) : std::vector<Eigen::Index>();
  const std::vector<Eigen::Index>* sample =
      o.whole_source && static_cast<Eigen::Index>(sample_indices.size()) < source.cols() ? &sample_indices : nullptr;
  const Cloud& target = tree.points();
  if (target.cols() == 0) throw InputError("icp: target cloud is empty");
  IcpResult result;
  LazyNormals normals(tree, o.normal_neighbors);
  const Eigen::Vector3d target_centroid = target.rowwise().mean();
  LevelEnv env{tree, normals, o};
  env.target_radius = std::sqrt((target.colwise() - target_centroid).colwise().squaredNorm().mean());
  env.target_spacing = medianSpacing(tree);
  env.min_scale = initial.scale() * o.min_scale_ratio;
  env.max_scale = initial.scale() * o.max_scale_ratio;
  env.anchors = anchors && !anchors->empty() ? anchors : nullptr;
  if (o.error_metric == ErrorMetric::kPointToPlane && o.estimate_scale) {
    env.target_thickness2 = surfaceThickness2(tree, o.normal_neighbors, kThicknessSamples);
  }

  Sim3 current = initial;
  LevelSource level = levelSource(source, env);
  int iter = iterateCoarseLevels(source, sample, env, o, level, &current);
  const LevelOutcome fine = iterateLevel(source, env, 1.0, iter, level, sample, &current);
  iter += fine.iterations;
  if (fine.failed) {
    result.status = Status::kIcpNotConverged;
    result.message = fine.message;
    result.transform = current;
    result.iterations = iter;
    return result;
  }
  const bool converged = fine.converged;

  // Final correspondences (and their weights) at the converged pose, both directions when
  // symmetric, in the form the covariance takes: source point, target point, residual normal.
  // The levels' source tree, spacing and normals serve here too (the same cloud).
  const Cloud moved = current.apply(source);
  const bool plane = o.error_metric == ErrorMetric::kPointToPlane;
  const bool symmetric = o.symmetric && plane;
  const bool source_checks = o.reciprocal || symmetric;
  const MatchContext ctx{tree, source_checks ? level.tree.get() : nullptr, current,
                         std::max(env.target_spacing, (source_checks ? level.spacing : 0.0) * current.scale())};
  NearestTargetD2 nearest_d2;
  std::vector<Match> m = matchAndReject(moved, ctx, o, sample, &nearest_d2, &level.forward_hints);
  // The covariance's observability check needs target normals for both metrics.
  normals.ensure(m);
  std::vector<Match> reverse;
  if (symmetric) {
    // The whole sample's target sample, as its level drew it (targetSample(target, source size)).
    reverse =
        reverseMatchAndReject(moved, ctx, *level.tree, level.reverse_targets, o, nearest_d2, &level.reverse_hints);
    std::vector<Eigen::Index> used;
    for (const Match& r : reverse) used.push_back(r.source);
    level.normals->ensureIndices(used);
  }
  PlaneSet set = planeSet(moved, target, m, normals.normals(), reverse,
                          symmetric ? &level.normals->normals() : nullptr, current.rotation());
  double spread = 0.0;
  if (plane) {
    if (o.local_noise && symmetric) {
      applyLocalNoise(normals, *level.normals, current.scale(), o.normal_neighbors, ctx.spacing, &set);
    }
    applyPlaneKernel(o, ctx.spacing, &set);
    spread = set.spread;
  } else {
    spread = applyKernel(moved, target, nullptr, o, ctx.spacing, &m);
    for (std::size_t k = 0; k < m.size(); ++k) set.weight[k] = m[k].weight;
  }
  result.transform = current;
  result.iterations = iter;
  result.converged = converged;
  result.correspondences = static_cast<int>(set.size());
  Correspondences& c = result.matches;
  c.residual_scale = spread;
  c.spacing = ctx.spacing;
  c.redundancy = designEffect(set, moved, target, plane);
  const double sum_d2 = fillMatches(set, source, target, &c);
  result.fitness_rmse = set.size() == 0 ? 0.0 : std::sqrt(sum_d2 / static_cast<double>(set.size()));
  setFinalStatus(set.size(), converged, iter, o, &result);
  return result;
}

void addAnchorNormalEquations(const PointMatch3& a, const Sim3& current, const Eigen::Vector3d& c,
                              Eigen::Matrix<double, 7, 7>* h, Eigen::Matrix<double, 7, 1>* g) {
  const Eigen::Vector3d y = current.apply(a.source);
  const Eigen::Vector3d r = y - a.target;
  const Eigen::Matrix3d w = a.covariance.inverse();
  const double m2 = r.dot(w * r);
  if (!std::isfinite(m2)) return;
  const double k = 1.0 / (1.0 + m2 / (kAnchorKernelWidth * kAnchorKernelWidth));
  const Eigen::Matrix<double, 3, 7> j = similarityJacobian(y - c);
  h->noalias() += k * j.transpose() * w * j;
  if (g) g->noalias() += k * j.transpose() * w * r;
}

void addAnchorNormalEquations(const std::vector<PointMatch3>& anchors, const Sim3& current, const Eigen::Vector3d& c,
                              Eigen::Matrix<double, 7, 7>* h, Eigen::Matrix<double, 7, 1>* g) {
  for (const PointMatch3& a : anchors) addAnchorNormalEquations(a, current, c, h, g);
}

}  // namespace pcr_pro
