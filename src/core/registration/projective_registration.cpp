#include "pcr_pro/registration/projective_registration.h"

#include <Eigen/Cholesky>
#include <opencv2/imgproc.hpp>
#ifdef _OPENMP
#include <omp.h>
#endif

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <utility>
#include <vector>

#include "pcr_pro/geometry/median.h"
#include "pcr_pro/registration/covariance.h"
#include "pcr_pro/registration/icp.h"
#include "pcr_pro/registration/jackknife.h"

namespace pcr_pro {
namespace {

// Fewer matches than this do not hold 7 DoF (each match gives two residuals, but a handful of
// them on one edge leave most directions free).
constexpr int kMinMatches = 7;
// Median of a chi-square with 2 DoF: the median squared Mahalanobis length of a residual pair
// that follows its noise model.
constexpr double kMedianChi2Of2 = 1.3863;
// The moving points are matched in this many contiguous chunks (matchesAt()).
constexpr std::size_t kMatchChunks = 64;
// The differential stop check's thresholds: the ICP's defaults.
const IcpOptions kStop;
// Median of a chi-square with 1 DoF: the median squared whitened depth residual of matches whose
// depth follows its noise model (depthDisagreement()).
constexpr double kMedianChi2Of1 = 0.4549;
// The two maps' relative depth disagreement is searched up to this [-] (100 % of the depth: beyond
// it the depth says nothing).
constexpr double kMaxDepthDisagreement = 1.0;
// The smallest standard deviation of an intensity difference [grey levels]: 8-bit quantisation,
// 1/sqrt(12), in each of the two images.
constexpr double kMinIntensityStddev = 0.41;
// A fixed keyframe's depth nearer than a projected point by more than this many of its standard
// deviations hides the point: its intensity there is another surface's.
constexpr double kOcclusionSigmas = 3.0;

using Vector7d = Eigen::Matrix<double, 7, 1>;
using Jacobian = Eigen::Matrix<double, 2, 7>;

// A pixel of the moving map's keyframes as a 3D point in its map, with its depth error: the error
// vector along its view ray per unit of depth, and its depth's variance.
struct MovingPoint {
  Eigen::Vector3d p;
  Eigen::Vector3d ray_error;  // per unit of depth standard deviation [map units per camera unit]
  double depth_var = 0.0;     // its depth's variance [camera units^2]
  float intensity = 0.0f;     // its grey level in its keyframe's smoothed image
  int keyframe = 0;           // the index of its keyframe in its map
};

// The grey image as float, smoothed by a Gaussian of `blur` px (ProjectiveOptions::photometric_blur_px).
cv::Mat smoothed(const cv::Mat& image, double blur) {
  cv::Mat f;
  image.convertTo(f, CV_32F);
  if (blur > 0.0) cv::GaussianBlur(f, f, cv::Size(0, 0), blur);
  return f;
}

// A keyframe of the fixed map: map -> camera, its depth and standard deviation [camera units] and
// its grey image's gradient.
struct FixedKeyframe {
  Sim3 map_to_camera;
  cv::Mat depth, stddev, gx, gy;
  cv::Mat grey, grey_dx, grey_dy;  // the smoothed image and its derivatives [grey levels per px]
};

struct Match {
  Jacobian j = Jacobian::Zero();
  Eigen::Vector2d r = Eigen::Vector2d::Zero();
  Eigen::Matrix2d information = Eigen::Matrix2d::Identity();  // the residual pair's inverse covariance
  double chi2 = 0.0;
  // The parts of the pair's covariance (covarianceAt()): the fixed pixel's depth variance and squared
  // depth, the edge's variance, the moving point's depth variance, and what the two residuals see of
  // a unit of its depth error.
  double fixed_var = 0.0, fixed_depth2 = 0.0, edge_var = 0.0, moving_var = 0.0;
  Eigen::Vector2d seen = Eigen::Vector2d::Zero();
  int moving_keyframe = 0, fixed_keyframe = 0;  // the keyframes of the moving point and of the pixel
};

// The residual pair's covariance when the fixed pixel's depth also disagrees with the moving map by
// a relative rho (depthDisagreement()). Only the depth residual gains it: the same relative error
// put on the moving point's ray as well (what it sees in the other keyframe) made the real LSD-SLAM
// maps slide 18-140 deg away again, since the IRLS weighs a covariance that grows with the estimate's
// scale without paying for it (docs/DESIGN.md).
Eigen::Matrix2d covarianceAt(const Match& m, double rho2) {
  Eigen::Matrix2d c;
  c << m.fixed_var + rho2 * m.fixed_depth2, 0.0, 0.0, m.edge_var;
  c += m.moving_var * m.seen * m.seen.transpose();
  return c;
}

// Sets the match's information (the inverse of covarianceAt()) and squared Mahalanobis length.
void setNoise(double rho2, Match* m) {
  m->information = covarianceAt(*m, rho2).inverse();
  m->chi2 = m->r.dot(m->information * m->r);
}

bool usable(float z, float sd, double max_relative) {
  return std::isfinite(z) && std::isfinite(sd) && z > 0.0f && sd > 0.0f && sd <= max_relative * z;
}

// The map's points; their grey levels come from the same map's keyframes as fixedKeyframes() made
// them (smoothed once per keyframe; 0 without ProjectiveOptions::photometric).
std::vector<MovingPoint> movingPoints(const AgentMap& map, const std::vector<FixedKeyframe>& frames,
                                      const ProjectiveOptions& o) {
  std::vector<MovingPoint> out;
  const PinholeCamera& k = map.camera;
  for (std::size_t index = 0; index < map.keyframes.size(); ++index) {
    const MapKeyframe& kf = map.keyframes[index];
    const cv::Mat& grey = frames[index].grey;
    long n = 0;
    for (int row = 0; row < kf.depth.rows; ++row) {
      const float* z = kf.depth.ptr<float>(row);
      const float* sd = kf.depth_stddev.ptr<float>(row);
      for (int col = 0; col < kf.depth.cols; ++col) {
        if (!usable(z[col], sd[col], o.max_relative_stddev) || n++ % o.pixel_step != 0) continue;
        const Eigen::Vector3d ray((col - k.cx) / k.fx, (row - k.cy) / k.fy, 1.0);
        const Eigen::Vector3d camera_point = static_cast<double>(z[col]) * ray;
        out.push_back({kf.pose.apply(camera_point), kf.pose.scale() * (kf.pose.rotation() * ray),
                       static_cast<double>(sd[col]) * sd[col], grey.empty() ? 0.0f : grey.at<float>(row, col),
                       static_cast<int>(index)});
      }
    }
  }
  return out;
}

std::vector<FixedKeyframe> fixedKeyframes(const AgentMap& map, const ProjectiveOptions& o) {
  std::vector<FixedKeyframe> out;
  for (const MapKeyframe& kf : map.keyframes) {
    FixedKeyframe f;
    f.map_to_camera = kf.pose.inverse();
    f.depth = kf.depth;
    f.stddev = kf.depth_stddev;
    cv::Sobel(kf.image, f.gx, CV_32F, 1, 0, 3);
    cv::Sobel(kf.image, f.gy, CV_32F, 0, 1, 3);
    if (o.photometric) {
      f.grey = smoothed(kf.image, o.photometric_blur_px);
      cv::Sobel(f.grey, f.grey_dx, CV_32F, 1, 0, 1, 0.5);  // central differences
      cv::Sobel(f.grey, f.grey_dy, CV_32F, 0, 1, 1, 0.5);
    }
    out.push_back(std::move(f));
  }
  return out;
}

// d(u, v) / d(camera point) of the pinhole projection at c.
Eigen::Matrix<double, 2, 3> projectionJacobian(const PinholeCamera& k, const Eigen::Vector3d& c) {
  const double iz = 1.0 / c.z();
  Eigen::Matrix<double, 2, 3> p;
  p << k.fx * iz, 0.0, -k.fx * c.x() * iz * iz, 0.0, k.fy * iz, -k.fy * c.y() * iz * iz;
  return p;
}

// The residual pair of a point at c in a keyframe's camera, projected at (u, v), against a fixed
// pixel (u0, v0) with depth z0: the depth difference, and the offset across the edge direction n.
Eigen::Vector2d residual(const Eigen::Vector3d& c, double u, double v, double u0, double v0, double z0,
                         const Eigen::Vector2d& n) {
  return Eigen::Vector2d(c.z() - z0, n.dot(Eigen::Vector2d(u - u0, v - v0)));
}

// Its Jacobian in the left perturbation of the similarity, from jc = d(camera point) / d(perturbation)
// and p = d(u, v) / d(camera point).
Jacobian residualJacobian(const Eigen::Matrix<double, 3, 7>& jc, const Eigen::Matrix<double, 2, 3>& p,
                          const Eigen::Vector2d& n) {
  Jacobian j;
  j.row(0) = jc.row(2);
  j.row(1) = n.transpose() * p * jc;
  return j;
}

// The matches of one moving point at S, one per fixed keyframe it projects into with a pixel with
// depth near it, with their noise and squared Mahalanobis length, appended to `out`. rho2 is the
// squared relative depth disagreement of the two maps (depthDisagreement()): the depth residual's
// variance gains rho2 z0^2.
void matchPoint(const Sim3& s, const MovingPoint& point, const std::vector<FixedKeyframe>& frames,
                const PinholeCamera& k, const ProjectiveOptions& o, double rho2, std::vector<Match>* out) {
  const int rad = o.search_radius_px;
  const double edge2 = o.edge_stddev_px * o.edge_stddev_px;
  const Eigen::Vector3d y = s.apply(point.p);
  const Eigen::Vector3d error = s.scale() * (s.rotation() * point.ray_error);
  for (std::size_t fi = 0; fi < frames.size(); ++fi) {
    const FixedKeyframe& f = frames[fi];
    const Eigen::Vector3d c = f.map_to_camera.apply(y);
    double u = 0.0, v = 0.0;
    if (!k.project(c, &u, &v)) continue;
    if (!(u >= rad + 1.0 && v >= rad + 1.0 && u < f.depth.cols - rad - 2.0 && v < f.depth.rows - rad - 2.0)) continue;
    const int cu = static_cast<int>(std::lround(u)), cv0 = static_cast<int>(std::lround(v));
    const Eigen::Matrix<double, 2, 3> p = projectionJacobian(k, c);
    // The moving point's own error in this keyframe's camera: the two residuals see it to first
    // order as its depth and its offset across the edge.
    const Eigen::Vector3d ec = f.map_to_camera.scale() * (f.map_to_camera.rotation() * error);
    // Of the pixels with depth within the radius, the one the noise model finds likeliest to be
    // the same point (the smallest squared Mahalanobis length of the residual pair). The nearest
    // pixel in the image is often across a depth edge, since semi-dense depth lies on edges: on
    // real LSD-SLAM keyframes the estimate then ran away (docs/DESIGN.md).
    Match m;
    m.chi2 = std::numeric_limits<double>::infinity();
    Eigen::Vector2d best_n = Eigen::Vector2d::Zero();
    for (int dv = -rad; dv <= rad; ++dv) {
      for (int du = -rad; du <= rad; ++du) {
        const int bu = cu + du, bv = cv0 + dv;
        if (!usable(f.depth.at<float>(bv, bu), f.stddev.at<float>(bv, bu), o.max_relative_stddev)) continue;
        Eigen::Vector2d n(f.gx.at<float>(bv, bu), f.gy.at<float>(bv, bu));
        if (!(n.norm() > 0.0)) continue;
        n.normalize();
        const double sd0 = f.stddev.at<float>(bv, bu), z0 = f.depth.at<float>(bv, bu);
        Match candidate;
        candidate.r = residual(c, u, v, bu, bv, z0, n);
        candidate.fixed_var = sd0 * sd0;
        candidate.fixed_depth2 = z0 * z0;
        candidate.edge_var = edge2;
        candidate.moving_var = point.depth_var;
        candidate.seen = Eigen::Vector2d(ec.z(), n.dot(p * ec));
        setNoise(rho2, &candidate);
        if (candidate.chi2 < m.chi2) m = candidate, best_n = n;
      }
    }
    if (!std::isfinite(m.chi2)) continue;
    const Eigen::Matrix<double, 3, 7> jc = f.map_to_camera.scale() * f.map_to_camera.rotation() * similarityJacobian(y);
    m.j = residualJacobian(jc, p, best_n);
    m.moving_keyframe = point.keyframe;
    m.fixed_keyframe = static_cast<int>(fi);
    out->push_back(m);
  }
}

// Runs body(chunk) for every chunk in [0, count), each chunk writing only its own outputs, so the
// result is the same on any number of threads. Inside a parallel region (the two directions and the
// jackknife's leave-outs run side by side, registerProjective()) the chunks are tasks of the team: a
// thread whose own registration has ended then takes chunks of the others' instead of waiting (on
// the real LSD-SLAM maps one direction moves 2.8 times the other's points). Outside one, a parallel
// loop.
template <class Body>
void forEachChunk(std::size_t count, const Body& body) {
#ifdef _OPENMP
  if (omp_in_parallel()) {
#pragma omp taskloop grainsize(1)
    for (std::size_t chunk = 0; chunk < count; ++chunk) body(chunk);
    return;
  }
#endif
#pragma omp parallel for schedule(dynamic)
  for (std::size_t chunk = 0; chunk < count; ++chunk) body(chunk);
}

// Chunk c of n over [0, size): its first index and one past its last.
std::pair<std::size_t, std::size_t> chunkRange(std::size_t size, std::size_t c, std::size_t n) {
  return {size * c / n, size * (c + 1) / n};
}

// One intensity comparison: a moving point projected into a fixed keyframe.
struct PhotometricRow {
  Eigen::Matrix<double, 1, 7> j;
  double r = 0.0;  // the fixed image's grey level there minus the point's own [grey levels]
  int pair = 0;    // moving keyframe * fixed keyframes + fixed keyframe
};

// Items collected in chunks, one per task, and read in chunk order as one sequence: the same
// sequence on any number of threads, without copying the chunks into one vector.
template <class T>
struct Chunked {
  std::vector<std::vector<T>> chunks;
  std::size_t size() const {
    std::size_t n = 0;
    for (const std::vector<T>& c : chunks) n += c.size();
    return n;
  }
  /// Calls f on every item, in order.
  template <class F>
  void each(const F& f) {
    for (std::vector<T>& c : chunks) {
      for (T& item : c) f(item);
    }
  }
  template <class F>
  void each(const F& f) const {
    for (const std::vector<T>& c : chunks) {
      for (const T& item : c) f(item);
    }
  }
  /// Empties the chunks and keeps count of them, their memory kept.
  void reset(std::size_t count) {
    chunks.resize(count);
    for (std::vector<T>& c : chunks) c.clear();
  }
};

// The buffers of one registration's iterations, kept from one iteration to the next: each
// iteration fills them again to about the same size. Allocated anew each time, and joined into one
// vector, they cost fresh pages from the kernel and a copy: in a profile of the real LSD-SLAM maps'
// merges, about a tenth of the time in page faults and 7 % in the copy.
struct Workspace {
  Chunked<Match> matches;
  Chunked<PhotometricRow> rows;
  std::vector<std::vector<double>> per_pair;
  std::vector<double> values;
  std::vector<std::size_t> offsets;
};

// Every match of the moving points at S, in the order of the points and keyframes, into
// ws->matches. The points are split into a fixed number of contiguous chunks, each collecting its
// own matches: the same sequence on any number of threads.
Chunked<Match>& matchesAt(const Sim3& s, const std::vector<MovingPoint>& points, const std::vector<FixedKeyframe>& frames,
                          const PinholeCamera& k, const ProjectiveOptions& o, double rho2, Workspace* ws) {
  const std::size_t chunk_count = std::min<std::size_t>(kMatchChunks, std::max<std::size_t>(1, points.size()));
  ws->matches.reset(chunk_count);
  forEachChunk(chunk_count, [&](std::size_t chunk) {
    const auto [begin, end] = chunkRange(points.size(), chunk, chunk_count);
    for (std::size_t i = begin; i < end; ++i) matchPoint(s, points[i], frames, k, o, rho2, &ws->matches.chunks[chunk]);
  });
  return ws->matches;
}

struct Direction {
  Sim3 estimate;
  Matrix7d information = Matrix7d::Zero();
  double median_chi2 = std::numeric_limits<double>::infinity();
  // The same under the two maps' per-pixel noise alone (rho = 0): how well the direction's data fit
  // that model, the direction choice's measure (rho makes every direction's depth fit by construction).
  double per_pixel_median_chi2 = std::numeric_limits<double>::infinity();
  double rho2 = 0.0;  // squared relative depth disagreement (depthDisagreement())
  int photometric_rows = 0;
  double photometric_stddev = 0.0;  // [grey levels] (photometricEquations())
  int matches = 0, iterations = 0, extrapolations = 0;
  // The geometric matches at the final estimate per moving and per fixed keyframe (by index).
  std::vector<int> moving_matches, fixed_matches;
  bool ok = false;
  bool converged = false;  // the differential check passed before max_iterations
};

// The two maps' relative depth disagreement beyond their per-pixel noise, from the matches' own
// depth residuals: the smallest rho >= 0 for which the median of r_d^2 / (v + rho^2 z0^2), v the
// depth residual's variance from the two maps' per-pixel noise, is the median of a chi-square with
// 1 DoF, i.e. what a depth residual that follows its noise model would have. Zero when the depth
// residuals are no larger than the two maps' per-pixel variance says (within one LSD-SLAM map; the
// bench's simulated worlds, in the direction kept). Two independent monocular maps also differ by
// their scale drift and distortion, which grow with depth: on the real LSD-SLAM maps of 7-Scenes
// rho was 0.13-0.25, and without it the depth residuals, weighed as if exact to their variance,
// made the estimate slide 21-165 deg away (docs/DESIGN.md; with it the slide was slower,
// and the grey levels stopped it). The matches' chi2 and information are updated to rho (the pixel
// chosen per match stays the one chosen at the previous rho). Every match is the likeliest pixel of
// several, which lowers its residual: rho is then, if anything, too small, never raised by the
// selection. @return rho^2
double depthDisagreement(Chunked<Match>* matches, double previous_rho2, Workspace* ws) {
  // No search: a match's r_d^2 / (v + rho^2 z0^2) is at most the chi-square's median c exactly when
  // rho^2 >= t = (r_d^2 / c - v) / z0^2, so as many of them are at most c as there are t at most
  // rho^2, and the ratios' upper median is at most c from the t's upper median on. That t is the
  // smallest rho^2, exactly and in one partial sort (a bisection to 0.1 % took about 16).
  // Both loops are per match, so they give the same result on any number of threads.
  const std::size_t chunks = matches->chunks.size();
  std::vector<std::size_t>& offset = ws->offsets;  // of each chunk's first match in t
  offset.assign(chunks + 1, 0);
  for (std::size_t c = 0; c < chunks; ++c) offset[c + 1] = offset[c] + matches->chunks[c].size();
  std::vector<double>& t = ws->values;
  t.resize(offset[chunks]);
  forEachChunk(chunks, [&](std::size_t c) {
    const std::vector<Match>& mine = matches->chunks[c];
    for (std::size_t i = 0; i < mine.size(); ++i) {
      const Match& m = mine[i];
      const double excess = m.r(0) * m.r(0) / kMedianChi2Of1 - covarianceAt(m, 0.0)(0, 0);
      t[offset[c] + i] = m.fixed_depth2 > 0.0 ? excess / m.fixed_depth2
                                              : (excess > 0.0 ? std::numeric_limits<double>::infinity() : 0.0);
    }
  });
  const double smallest = upperMedian(&t);
  const double rho2 = smallest > 0.0 ? std::min(smallest, kMaxDepthDisagreement * kMaxDepthDisagreement) : 0.0;
  if (rho2 == previous_rho2) return rho2;
  forEachChunk(chunks, [&](std::size_t c) {
    for (Match& m : matches->chunks[c]) setNoise(rho2, &m);
  });
  return rho2;
}

// The matches at S with the two maps' depth disagreement re-estimated from them (when the option is
// on): d->rho2 is updated. @return ws->matches
Chunked<Match>& matchesWithDisagreement(const Sim3& s, const std::vector<MovingPoint>& points,
                                        const std::vector<FixedKeyframe>& frames, const PinholeCamera& k,
                                        const ProjectiveOptions& o, Direction* d, Workspace* ws) {
  matchesAt(s, points, frames, k, o, d->rho2, ws);
  if (o.depth_disagreement && static_cast<int>(ws->matches.size()) >= kMinMatches) {
    d->rho2 = depthDisagreement(&ws->matches, d->rho2, ws);
  }
  return ws->matches;
}

// The IRLS normal equations of the matches: Cauchy weights on the squared Mahalanobis lengths
// over their robust spread (their median over the chi-square's, at least 1: residuals that follow
// their noise model keep it).
void normalEquations(const Chunked<Match>& matches, double width, Matrix7d* h, Vector7d* g, double* median_chi2,
                     Workspace* ws) {
  std::vector<double>& chi2 = ws->values;
  chi2.clear();
  matches.each([&](const Match& m) { chi2.push_back(m.chi2); });
  *median_chi2 = upperMedian(&chi2);
  const double spread = std::max(1.0, *median_chi2 / kMedianChi2Of2);
  h->setZero();
  g->setZero();
  matches.each([&](const Match& m) {
    const double w = 1.0 / (1.0 + m.chi2 / (spread * width * width));
    const Eigen::Matrix2d& ci = m.information;
    *h += w * m.j.transpose() * ci * m.j;
    *g += w * m.j.transpose() * ci * m.r;
  });
  *h /= spread;
  *g /= spread;
}

float bilinear(const cv::Mat& m, double u, double v) {
  const int x = static_cast<int>(u), y = static_cast<int>(v);
  const float a = static_cast<float>(u - x), b = static_cast<float>(v - y);
  return (1 - a) * (1 - b) * m.at<float>(y, x) + a * (1 - b) * m.at<float>(y, x + 1) +
         (1 - a) * b * m.at<float>(y + 1, x) + a * b * m.at<float>(y + 1, x + 1);
}

// The photometric rows of the moving points at S (ProjectiveOptions::photometric): every point
// that projects inside a fixed keyframe, and is not hidden there by a nearer surface of that
// keyframe's depth, compares its grey level with the fixed image's at its projection (bilinear),
// whose gradient gives the Jacobian. Unlike the depth and edge residuals, this needs no pixel with
// depth near the projection, so it holds the estimate where those let it slide (docs/DESIGN.md).
// Chunked as matchesAt(), into ws->rows.
Chunked<PhotometricRow>& photometricRowsAt(const Sim3& s, const std::vector<MovingPoint>& points,
                                           const std::vector<FixedKeyframe>& frames, const PinholeCamera& k,
                                           double rho2, Workspace* ws) {
  const std::size_t chunk_count = std::min<std::size_t>(kMatchChunks, std::max<std::size_t>(1, points.size()));
  ws->rows.reset(chunk_count);
  const int nf = static_cast<int>(frames.size());
  forEachChunk(chunk_count, [&](std::size_t chunk) {
    std::vector<PhotometricRow>& mine = ws->rows.chunks[chunk];
    const auto [begin, end] = chunkRange(points.size(), chunk, chunk_count);
    for (std::size_t i = begin; i < end; ++i) {
      const MovingPoint& point = points[i];
      const Eigen::Vector3d y = s.apply(point.p);
      for (int fi = 0; fi < nf; ++fi) {
        const FixedKeyframe& f = frames[fi];
        const Eigen::Vector3d c = f.map_to_camera.apply(y);
        double u = 0.0, v = 0.0;
        if (!k.project(c, &u, &v)) continue;
        if (!(u >= 1.0 && v >= 1.0 && u < f.grey.cols - 2.0 && v < f.grey.rows - 2.0)) continue;
        const int cu = static_cast<int>(std::lround(u)), cv0 = static_cast<int>(std::lround(v));
        const float z0 = f.depth.at<float>(cv0, cu), sd0 = f.stddev.at<float>(cv0, cu);
        if (std::isfinite(z0) && std::isfinite(sd0) && z0 > 0.0f &&
            z0 + kOcclusionSigmas * std::sqrt(sd0 * sd0 + rho2 * z0 * z0) < c.z()) {
          continue;
        }
        const Eigen::RowVector2d gradient(bilinear(f.grey_dx, u, v), bilinear(f.grey_dy, u, v));
        const Eigen::Matrix<double, 3, 7> jc =
            f.map_to_camera.scale() * f.map_to_camera.rotation() * similarityJacobian(y);
        PhotometricRow row;
        row.j = gradient * projectionJacobian(k, c) * jc;
        row.r = bilinear(f.grey, u, v) - point.intensity;
        row.pair = point.keyframe * nf + fi;
        mine.push_back(row);
      }
    }
  });
  return ws->rows;
}

// Adds the photometric rows' IRLS normal equations to h and g. Each pair of keyframes has its own
// brightness offset (the agents' cameras expose differently, and so do one camera's keyframes): the
// median of the pair's differences, taken off. The intensity noise is the rows' robust spread (1.4826
// times their median absolute difference, at least the 8-bit quantisation of two images), re-measured
// every iteration as the depth disagreement is; Cauchy weights of the same width as the geometric
// residuals'. @return that noise [grey levels], 0 when there are too few rows (fewer than kMinMatches)
double photometricEquations(Chunked<PhotometricRow>* rows, double width, Matrix7d* h, Vector7d* g,
                            Workspace* ws) {
  if (static_cast<int>(rows->size()) < kMinMatches) return 0.0;
  // Per pair of keyframes, indexed by PhotometricRow::pair (a dense index), each pair's differences
  // in the rows' order.
  int pairs = 0;
  rows->each([&](const PhotometricRow& row) { pairs = std::max(pairs, row.pair + 1); });
  std::vector<std::vector<double>>& per_pair = ws->per_pair;
  per_pair.resize(static_cast<std::size_t>(pairs));
  for (std::vector<double>& v : per_pair) v.clear();
  rows->each([&](const PhotometricRow& row) { per_pair[static_cast<std::size_t>(row.pair)].push_back(row.r); });
  std::vector<double> offset(per_pair.size());
  for (std::size_t pair = 0; pair < per_pair.size(); ++pair) offset[pair] = upperMedian(&per_pair[pair]);
  std::vector<double>& absolute = ws->values;
  absolute.clear();
  rows->each([&](PhotometricRow& row) {
    row.r -= offset[static_cast<std::size_t>(row.pair)];
    absolute.push_back(std::abs(row.r));
  });
  const double sigma = std::max(kMinIntensityStddev, 1.4826 * upperMedian(&absolute));
  std::as_const(*rows).each([&](const PhotometricRow& row) {
    const double z2 = row.r * row.r / (sigma * sigma);
    const double w = 1.0 / (1.0 + z2 / (width * width)) / (sigma * sigma);
    *h += w * row.j.transpose() * row.j;
    *g += w * row.j.transpose() * row.r;
  });
  return sigma;
}

// The normal equations at S of the geometric matches (normalEquations()) plus, with the option, the
// photometric rows (photometricEquations()). @return the geometric matches (ws->matches)
const Chunked<Match>& equationsAt(const Sim3& s, const std::vector<MovingPoint>& points,
                                  const std::vector<FixedKeyframe>& frames, const PinholeCamera& k,
                                  const ProjectiveOptions& o, Direction* d, Vector7d* g, Workspace* ws) {
  const Chunked<Match>& matches = matchesWithDisagreement(s, points, frames, k, o, d, ws);
  if (static_cast<int>(matches.size()) < kMinMatches) return matches;
  normalEquations(matches, o.kernel_width, &d->information, g, &d->median_chi2, ws);
  d->matches = static_cast<int>(matches.size());
  if (o.photometric) {
    Chunked<PhotometricRow>& rows = photometricRowsAt(s, points, frames, k, d->rho2, ws);
    d->photometric_rows = static_cast<int>(rows.size());
    d->photometric_stddev = photometricEquations(&rows, o.kernel_width, &d->information, g, ws);
  }
  return matches;
}

Direction solve(const std::vector<MovingPoint>& points, const std::vector<FixedKeyframe>& frames,
                const PinholeCamera& k, const Sim3& initial, const ProjectiveOptions& o) {
  Direction d;
  d.estimate = initial;
  if (points.empty()) return d;
  Workspace ws;
  // The moving points' RMS radius about their centroid [moving map units]: the length scale of the
  // translation's convergence check.
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const MovingPoint& m : points) centroid += m.p / static_cast<double>(points.size());
  double radius2 = 0.0;
  for (const MovingPoint& m : points) radius2 += (m.p - centroid).squaredNorm() / static_cast<double>(points.size());
  const double radius = std::sqrt(radius2);
  Vector7d previous = Vector7d::Zero();
  double previous_ratio = std::numeric_limits<double>::infinity();  // |previous| / |the one before|
  for (int it = 0; it < o.max_iterations; ++it) {
    Vector7d g;
    if (static_cast<int>(equationsAt(d.estimate, points, frames, k, o, &d, &g, &ws).size()) < kMinMatches) return d;
    const Eigen::LDLT<Matrix7d> ldlt(d.information);
    if (ldlt.info() != Eigen::Success) return d;
    const Vector7d step = -ldlt.solve(g);
    if (!step.allFinite()) return d;
    d.iterations = it + 1;
    // Converged when the step passes the ICP's differential check at its default thresholds
    // (IcpOptions: 1e-4 rad, 1e-4 in scale, 1e-4 of the moving points' RMS radius), far below the
    // noise of either map.
    const bool small = step.segment<3>(3).norm() < kStop.min_rotation_change &&
                       std::abs(step(6)) < kStop.min_scale_change &&
                       step.head<3>().norm() < kStop.min_relative_translation_change * radius * d.estimate.scale();
    // Re-made matches let the estimate creep: successive steps point the same way (cosine about
    // 0.99 in the information's metric) and shrink slowly. The rest of their geometric series is
    // taken at once, as the ICP does (IcpOptions::extrapolation), but only once the steps have shrunk
    // twice running: after steps that grew (a long way to go, as from a start far off) the first
    // smaller one is no series yet, and extrapolating it overshot and kept the estimate swinging
    // (with the photometric rows, on the unit test's worlds of unequal noise: still moving after 60
    // iterations, 0.5-2.4 deg off, where without it 10-14 iterations ended 0.004-0.018 deg away).
    double factor = 1.0;
    const double a = step.dot(d.information * step), b = previous.dot(d.information * previous);
    const double ratio = b > 0.0 ? std::sqrt(a / b) : std::numeric_limits<double>::infinity();
    if (o.extrapolation && !small) {
      const double cosine = a > 0.0 && b > 0.0 ? step.dot(d.information * previous) / std::sqrt(a * b) : 0.0;
      if (cosine > kExtrapolationMinCosine && ratio < 1.0 && previous_ratio < 1.0) {
        factor = 1.0 + std::min(kExtrapolationMaxFactor, ratio / (1.0 - ratio));
        ++d.extrapolations;
      }
    }
    previous_ratio = ratio;
    previous = step;
    d.estimate = applyDelta(factor * step, d.estimate);
    if (small) {
      d.converged = true;
      break;
    }
  }
  // The noise model's fit and the information at the final estimate.
  Vector7d g;
  const Chunked<Match>& matches = equationsAt(d.estimate, points, frames, k, o, &d, &g, &ws);
  if (static_cast<int>(matches.size()) < kMinMatches) return d;
  int moving_keyframes = 0;
  for (const MovingPoint& m : points) moving_keyframes = std::max(moving_keyframes, m.keyframe + 1);
  d.moving_matches.assign(static_cast<std::size_t>(moving_keyframes), 0);
  d.fixed_matches.assign(frames.size(), 0);
  matches.each([&](const Match& m) {
    ++d.moving_matches[static_cast<std::size_t>(m.moving_keyframe)];
    ++d.fixed_matches[static_cast<std::size_t>(m.fixed_keyframe)];
  });
  d.per_pixel_median_chi2 = d.median_chi2;
  if (d.rho2 > 0.0) {
    std::vector<double> chi2;
    chi2.reserve(matches.size());
    matches.each([&](const Match& m) { chi2.push_back(m.r.dot(covarianceAt(m, 0.0).inverse() * m.r)); });
    d.per_pixel_median_chi2 = upperMedian(&chi2);
  }
  d.ok = d.estimate.matrix().allFinite() && d.information.allFinite();
  return d;
}

// The delete-one-keyframe jackknife of a direction (ProjectiveOptions::jackknife).
struct Jackknife {
  bool ok = false;
  Matrix7d covariance = Matrix7d::Zero();  // of δ about the direction's own estimate (moving -> fixed)
  int moving = 0, fixed = 0;               // keyframes left out whose registration gave an estimate
  int not_converged = 0;
};

// The direction solved again from its estimate without each keyframe that holds kMinMatches of its
// matches or more, one at a time: first each moving keyframe's points, then each fixed keyframe. A
// keyframe is what a monocular map gets wrong as a whole (its depth's scale, its pose's drift), so the
// estimates' spread between leave-outs holds those errors, which the per-pixel noise does not. The
// two maps' keyframes are crossed (every match pairs one of each), so each side is a jackknife of its
// own, (n - 1)/n Σ (δ_k - δ̄)(δ_k - δ̄)ᵀ over its n leave-outs, and the two are summed: each also
// holds the per-pixel noise, which is thus counted twice (conservative). A side needs two such
// keyframes or more; with one, what its keyframe gets wrong is not measured, and ok is false. A
// leave-out still moving at max_iterations counts, as in the ICP's jackknife (jackknife.h).
Jackknife jackknifeKeyframes(const std::vector<MovingPoint>& points, const std::vector<FixedKeyframe>& frames,
                             const PinholeCamera& k, const Direction& full, const ProjectiveOptions& o) {
  Jackknife out;
  // Every n-th moving point (ProjectiveOptions::jackknife_point_step), the same in every leave-out,
  // and the subsample's own estimate with every keyframe: the leave-outs start there, near their own
  // estimates. A subsample moves the estimate by far more than the Gauss-Newton covariance says: on
  // the real LSD-SLAM maps (1-in-4, 2026-12-06) the leave-outs started from the full estimate ended
  // 0.09-0.74 deg from it, against a Gauss-Newton 1-sigma of 0.006 deg, and took 1.8 times the
  // iterations of those started here.
  const std::size_t step = static_cast<std::size_t>(o.jackknife_point_step);
  std::vector<MovingPoint> every_nth;
  Sim3 start = full.estimate;
  if (step > 1) {
    every_nth.reserve(points.size() / step + 1);
    for (std::size_t i = 0; i < points.size(); i += step) every_nth.push_back(points[i]);
    const Direction base = solve(every_nth, frames, k, full.estimate, o);
    if (base.ok) start = base.estimate;
  }
  const std::vector<MovingPoint>& subsample = step > 1 ? every_nth : points;
  const auto add = [&](const Direction& r, std::vector<Vector7d>* deltas) {
    const Vector7d d = similarityDifference(r.estimate, start);
    if (!r.ok || !d.allFinite()) return;  // no estimate without that keyframe: not counted
    if (!r.converged) ++out.not_converged;
    deltas->push_back(d);
  };
  // The leave-outs: each moving keyframe with matches, then each fixed one. They are independent and
  // run side by side as tasks, one thread each, whose own loops' chunks any idle thread of the team
  // takes as well (forEachChunk(); the same result on any number of threads); more of the work is
  // then parallel than within one registration, whose robust medians and normal equations are
  // serial.
  std::vector<std::pair<bool, std::size_t>> jobs;  // (a moving keyframe?, its index)
  for (std::size_t kf = 0; kf < full.moving_matches.size(); ++kf) {
    if (full.moving_matches[kf] >= kMinMatches) jobs.emplace_back(true, kf);
  }
  for (std::size_t kf = 0; kf < full.fixed_matches.size(); ++kf) {
    if (full.fixed_matches[kf] >= kMinMatches) jobs.emplace_back(false, kf);
  }
  std::vector<Direction> results(jobs.size());
  const auto leave_out = [&](std::size_t job) {
    const auto [is_moving, kf] = jobs[job];
    if (is_moving) {
      std::vector<MovingPoint> kept;
      kept.reserve(subsample.size());
      for (const MovingPoint& m : subsample) {
        if (m.keyframe != static_cast<int>(kf)) kept.push_back(m);
      }
      results[job] = solve(kept, frames, k, start, o);
    } else {
      std::vector<FixedKeyframe> kept;
      for (std::size_t i = 0; i < frames.size(); ++i) {
        if (i != kf) kept.push_back(frames[i]);
      }
      results[job] = solve(subsample, kept, k, start, o);
    }
  };
#pragma omp parallel
#pragma omp single
  for (std::size_t job = 0; job < jobs.size(); ++job) {
#pragma omp task firstprivate(job)
    leave_out(job);
  }
  std::vector<Vector7d> moving, fixed;
  for (std::size_t job = 0; job < jobs.size(); ++job) add(results[job], jobs[job].first ? &moving : &fixed);
  out.moving = static_cast<int>(moving.size());
  out.fixed = static_cast<int>(fixed.size());
  if (out.moving < 2 || out.fixed < 2) return out;
  out.covariance = jackknifeSpread(moving) + jackknifeSpread(fixed);
  out.ok = out.covariance.allFinite();
  return out;
}

}  // namespace

bool hasDepthUncertainty(const AgentMap& map) {
  if (map.keyframes.empty()) return false;
  for (const MapKeyframe& kf : map.keyframes) {
    if (kf.depth.empty() || kf.depth_stddev.empty() || kf.image.type() != CV_8UC1 || kf.depth.type() != CV_32FC1 ||
        kf.depth_stddev.type() != CV_32FC1 || kf.depth.size() != kf.depth_stddev.size() ||
        kf.depth.cols != map.camera.width || kf.depth.rows != map.camera.height || kf.image.size() != kf.depth.size()) {
      return false;
    }
  }
  return true;
}

ProjectiveResult registerProjective(const AgentMap& source, const AgentMap& target, const Sim3& initial,
                                    const ProjectiveOptions& options) {
  validate(options);
  ProjectiveResult out;
  out.estimate = initial;
  for (const auto& [map, which] : {std::pair<const AgentMap*, const char*>{&source, "source"}, {&target, "target"}}) {
    if (!hasDepthUncertainty(*map)) {
      out.status = Status::kInvalidInput;
      out.message = std::string("projective registration: the ") + which +
                    " map's keyframes lack depth with a per-pixel standard deviation";
      return out;
    }
    for (const MapKeyframe& kf : map->keyframes) {
      if (!(kf.pose.scale() > 0.0) || !kf.pose.matrix().allFinite()) {
        out.status = Status::kInvalidInput;
        out.message = std::string("projective registration: ") + which + " keyframe " + std::to_string(kf.id) +
                      " has an invalid pose";
        return out;
      }
    }
    if (!map->camera.valid()) {
      out.status = Status::kInvalidInput;
      out.message = std::string("projective registration: the ") + which + " map's camera is invalid";
      return out;
    }
  }
  const std::vector<FixedKeyframe> source_frames = fixedKeyframes(source, options),
                                   target_frames = fixedKeyframes(target, options);
  const std::vector<MovingPoint> source_points = movingPoints(source, source_frames, options),
                                 target_points = movingPoints(target, target_frames, options);
  // The two directions side by side as tasks (as the jackknife's leave-outs): the thread that ends
  // its direction first then takes chunks of the other's loops.
  Direction forward, backward;
#pragma omp parallel
#pragma omp single
  {
#pragma omp task shared(forward)
    forward = solve(source_points, target_frames, target.camera, initial, options);
#pragma omp task shared(backward)
    backward = solve(target_points, source_frames, source.camera, initial.inverse(), options);
  }
  // The backward direction's own estimate B (source -> target is B⁻¹), kept for its jackknife.
  const Sim3 backward_own = backward.estimate;
  if (backward.ok) {
    // Into the requested direction, S = B⁻¹: its covariance is Ad(B⁻¹) C_B Ad(B⁻¹)ᵀ
    // (similarityAdjoint()), so its information is Ad(B)ᵀ I_B Ad(B).
    const Matrix7d ad = similarityAdjoint(backward.estimate);
    backward.information = ad.transpose() * backward.information * ad;
    backward.estimate = backward.estimate.inverse();
  }
  if (!forward.ok && !backward.ok) {
    out.status = Status::kNotEnoughMatches;
    out.message = "projective registration: fewer than " + std::to_string(kMinMatches) +
                  " point-keyframe matches in either direction";
    return out;
  }
  const bool use_backward =
      backward.ok && (!forward.ok || backward.per_pixel_median_chi2 < forward.per_pixel_median_chi2);
  const Direction& d = use_backward ? backward : forward;
  const Direction& other = use_backward ? forward : backward;
  const Eigen::LDLT<Matrix7d> ldlt(d.information);
  out.covariance = ldlt.solve(Matrix7d::Identity());
  out.covariance = 0.5 * (out.covariance + out.covariance.transpose()).eval();
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive() || !out.covariance.allFinite() ||
      !(ldlt.vectorD().minCoeff() > 0.0)) {
    out.status = Status::kNotEnoughMatches;
    out.message = "projective registration: the matches do not hold all 7 DoF";
    return out;
  }
  out.gauss_newton_covariance = out.covariance;
  // The centre of the overlap in the target map: the moving points' centroid, where the estimate
  // puts it. The spreads below are taken without their cross terms between the translation there,
  // the rotation and the log scale (blockDiagonalAt(), as the ICP's jackknife): a handful of
  // estimates resolve those correlations poorly.
  const std::vector<MovingPoint>& moving = use_backward ? target_points : source_points;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  for (const MovingPoint& m : moving) centre += m.p / static_cast<double>(moving.size());
  if (!use_backward) centre = d.estimate.apply(centre);
  if (options.jackknife) {
    // The jackknife runs in the kept direction's own frame; the backward one's spread moves into the
    // requested direction by the adjoint of B⁻¹, as its information did above.
    Direction own = d;
    if (use_backward) own.estimate = backward_own;
    const Jackknife jk = use_backward
                             ? jackknifeKeyframes(target_points, source_frames, source.camera, own, options)
                             : jackknifeKeyframes(source_points, target_frames, target.camera, own, options);
    out.jackknife_moving_keyframes = jk.moving;
    out.jackknife_fixed_keyframes = jk.fixed;
    out.jackknife_not_converged = jk.not_converged;
    if (jk.ok) {
      Matrix7d spread = jk.covariance;
      if (use_backward) {
        const Matrix7d ad = similarityAdjoint(d.estimate);
        spread = ad * spread * ad.transpose();
      }
      const Matrix7d c = out.covariance + blockDiagonalAt(spread, centre);
      out.jackknifed = c.allFinite();
      if (out.jackknifed) out.covariance = 0.5 * (c + c.transpose());
    }
  }
  if (options.direction_spread && other.ok) {
    // The two directions' difference δ, taken as a spread δδᵀ of the kept estimate along it.
    const Vector7d difference = similarityDifference(other.estimate, d.estimate);
    const Matrix7d c = out.covariance + blockDiagonalAt(difference * difference.transpose(), centre);
    if (difference.allFinite() && c.allFinite()) {
      out.covariance = 0.5 * (c + c.transpose());
      out.direction_difference_deg = difference.segment<3>(3).norm() * 180.0 / M_PI;
      out.direction_difference_scale = difference(6);
      out.direction_spread = true;
    }
  }
  out.status = d.converged ? Status::kOk : Status::kIcpNotConverged;
  out.estimate = d.estimate;
  out.extrapolations = d.extrapolations;
  out.median_chi2 = d.per_pixel_median_chi2;
  out.depth_disagreement = std::sqrt(d.rho2);
  out.photometric_rows = d.photometric_rows;
  out.photometric_stddev = d.photometric_stddev;
  out.matches = d.matches;
  out.reversed = use_backward;
  out.iterations = d.iterations;
  out.other_estimate = other.ok ? other.estimate : initial;
  out.other_median_chi2 = other.ok ? other.per_pixel_median_chi2 : std::numeric_limits<double>::infinity();
  char chi2[32];
  std::snprintf(chi2, sizeof chi2, "%.3g", out.median_chi2);
  out.message = std::string(use_backward ? "the target's points into the source's keyframes"
                                         : "the source's points into the target's keyframes") +
                ", " + std::to_string(out.matches) + " matches, median chi2 " + chi2;
  if (options.depth_disagreement) {
    char rho[32];
    std::snprintf(rho, sizeof rho, "%.3g", 100.0 * out.depth_disagreement);
    out.message += std::string(", depth disagreement ") + rho + " %";
  }
  if (options.photometric) {
    char sd[32];
    std::snprintf(sd, sizeof sd, "%.3g", out.photometric_stddev);
    out.message += ", " + std::to_string(out.photometric_rows) + " grey-level comparisons (noise " + sd + ")";
  }
  if (options.jackknife) {
    out.message += out.jackknifed
                       ? ", covariance from the jackknife over " + std::to_string(out.jackknife_moving_keyframes) +
                             " moving and " + std::to_string(out.jackknife_fixed_keyframes) + " fixed keyframes" +
                             (options.jackknife_point_step > 1
                                  ? " (1 in " + std::to_string(options.jackknife_point_step) + " moving points)"
                                  : std::string())
                       : ", no jackknife (" + std::to_string(out.jackknife_moving_keyframes) + " moving and " +
                             std::to_string(out.jackknife_fixed_keyframes) +
                             " fixed keyframes with matches left out; 2 of each needed): the covariance holds no "
                             "keyframe's error";
    if (out.jackknife_not_converged > 0) {
      out.message += " (" + std::to_string(out.jackknife_not_converged) + " leave-outs not converged)";
    }
  }
  if (out.direction_spread) {
    char dir[96];
    std::snprintf(dir, sizeof dir, ", the two directions %.3g deg and %.3g %% in scale apart",
                  out.direction_difference_deg, 100.0 * out.direction_difference_scale);
    out.message += dir;
  }
  if (!d.converged) {
    out.message = "projective registration: did not converge within " + std::to_string(options.max_iterations) +
                  " iterations (" + out.message + ")";
  }
  return out;
}

}  // namespace pcr_pro
