#include "pcr_pro/sim/render.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "sim/sim_random.h"

namespace pcr_pro {
namespace {

// A quad in the camera frame with its projected outline (the polygon clipped at z = near).
struct CameraQuad {
  Eigen::Vector3d o, u, v, n;
  double dist = 0.0;  // n . X = dist on the plane
  double inv_uu = 0.0, inv_vv = 0.0;
  int index = 0;
  std::vector<Eigen::Vector2d> outline;  // convex, in pixel coordinates
  double vmin = 0.0, vmax = 0.0;          // [px]

  // Columns [umin, umax] of the outline on image row v (with one pixel of slack: the exact
  // inside test is done per ray); false when the row misses it.
  bool span(double v, double* umin, double* umax) const {
    if (v < vmin - 1.0 || v > vmax + 1.0) return false;
    double lo = std::numeric_limits<double>::infinity(), hi = -lo;
    const std::size_t n_pts = outline.size();
    for (std::size_t i = 0; i < n_pts; ++i) {
      const Eigen::Vector2d& p = outline[i];
      const Eigen::Vector2d& q = outline[(i + 1) % n_pts];
      // The edge clamped to the row band [v - 1, v + 1], so that slivers are not missed.
      const double y0 = std::min(p.y(), q.y()), y1 = std::max(p.y(), q.y());
      if (y1 < v - 1.0 || y0 > v + 1.0) continue;
      for (double y : {std::clamp(v - 1.0, y0, y1), std::clamp(v + 1.0, y0, y1)}) {
        const double x = y1 - y0 > 1e-12 ? p.x() + (y - p.y()) / (q.y() - p.y()) * (q.x() - p.x()) : p.x();
        lo = std::min({lo, x, y1 - y0 > 1e-12 ? x : q.x()});
        hi = std::max({hi, x, y1 - y0 > 1e-12 ? x : q.x()});
      }
    }
    if (lo > hi) return false;
    *umin = lo - 1.0;
    *umax = hi + 1.0;
    return true;
  }
};

// One z-buffer sample: the nearest surface along a ray.
struct Hit {
  float z = std::numeric_limits<float>::infinity();
  int quad = -1;
  float a = 0.0f, b = 0.0f;  // quad coordinates of the hit, in [0, 1]
};

// Quads in front of the camera with their projected outlines.
std::vector<CameraQuad> cameraQuads(const World& world, const PinholeCamera& cam, const Sim3& camera_to_world,
                                    double near) {
  const Eigen::Matrix3d rt = camera_to_world.rotation().transpose();
  const Eigen::Vector3d& t = camera_to_world.translation();
  std::vector<CameraQuad> out;
  for (std::size_t k = 0; k < world.quads.size(); ++k) {
    const WorldQuad& wq = world.quads[k];
    CameraQuad q;
    q.o = rt * (wq.origin - t);
    q.u = rt * wq.axis_u;
    q.v = rt * wq.axis_v;
    q.n = q.u.cross(q.v).normalized();
    q.dist = q.n.dot(q.o);
    if (std::abs(q.dist) < 1e-9) continue;  // the camera lies in the plane: the quad is a line
    q.inv_uu = 1.0 / q.u.squaredNorm();
    q.inv_vv = 1.0 / q.v.squaredNorm();
    q.index = static_cast<int>(k);
    // Sutherland-Hodgman against the plane z = near.
    const Eigen::Vector3d corners[4] = {q.o, q.o + q.u, q.o + q.u + q.v, q.o + q.v};
    std::vector<Eigen::Vector3d> poly;
    for (int i = 0; i < 4; ++i) {
      const Eigen::Vector3d& p = corners[i];
      const Eigen::Vector3d& r = corners[(i + 1) % 4];
      const bool p_in = p.z() >= near, r_in = r.z() >= near;
      if (p_in) poly.push_back(p);
      if (p_in != r_in) poly.push_back(p + (near - p.z()) / (r.z() - p.z()) * (r - p));
    }
    if (poly.empty()) continue;
    double umin = std::numeric_limits<double>::infinity(), umax = -umin;
    q.vmin = umin, q.vmax = umax;
    for (const Eigen::Vector3d& p : poly) {
      q.outline.emplace_back(cam.fx * p.x() / p.z() + cam.cx, cam.fy * p.y() / p.z() + cam.cy);
      umin = std::min(umin, q.outline.back().x()), umax = std::max(umax, q.outline.back().x());
      q.vmin = std::min(q.vmin, q.outline.back().y()), q.vmax = std::max(q.vmax, q.outline.back().y());
    }
    if (umax < -2.0 || q.vmax < -2.0 || umin > cam.width + 1.0 || q.vmin > cam.height + 1.0) continue;
    out.push_back(std::move(q));
  }
  return out;
}

// Z-buffer of the rays through the image points (offset + i * step, v), i in [0, count).
void rasterizeRow(const std::vector<CameraQuad>& quads, const PinholeCamera& cam, double v, double offset,
                  double step, int count, double near, Hit* row) {
  std::fill(row, row + count, Hit());
  const double dy = (v - cam.cy) / cam.fy;
  for (const CameraQuad& q : quads) {
    double umin = 0.0, umax = 0.0;
    if (!q.span(v, &umin, &umax)) continue;
    const int i0 = std::max(0, static_cast<int>(std::ceil((umin - offset) / step)));
    const int i1 = std::min(count - 1, static_cast<int>(std::floor((umax - offset) / step)));
    const double ny = q.n.y() * dy + q.n.z();
    for (int i = i0; i <= i1; ++i) {
      const double dx = (offset + i * step - cam.cx) / cam.fx;
      const double denom = q.n.x() * dx + ny;
      if (std::abs(denom) < 1e-12) continue;
      const double z = q.dist / denom;  // the ray (dx, dy, 1) * z meets the plane
      Hit& h = row[i];
      if (!(z > near) || z >= h.z) continue;
      const Eigen::Vector3d d(dx * z - q.o.x(), dy * z - q.o.y(), z - q.o.z());
      const double a = d.dot(q.u) * q.inv_uu;
      if (a < 0.0 || a > 1.0) continue;
      const double b = d.dot(q.v) * q.inv_vv;
      if (b < 0.0 || b > 1.0) continue;
      h.z = static_cast<float>(z);
      h.quad = q.index;
      h.a = static_cast<float>(a);
      h.b = static_cast<float>(b);
    }
  }
}

// Bilinear lookup at texture coordinates (a, b) in [0, 1] of one mip level.
double bilinear(const cv::Mat& level, double a, double b) {
  const double x = std::clamp(a * level.cols - 0.5, 0.0, level.cols - 1.0);
  const double y = std::clamp(b * level.rows - 0.5, 0.0, level.rows - 1.0);
  const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);  // x, y >= 0: truncation is floor
  const int x1 = std::min(x0 + 1, level.cols - 1), y1 = std::min(y0 + 1, level.rows - 1);
  const double fx = x - x0, fy = y - y0;
  const float* r0 = level.ptr<float>(y0);
  const float* r1 = level.ptr<float>(y1);
  return (1.0 - fy) * ((1.0 - fx) * r0[x0] + fx * r0[x1]) + fy * ((1.0 - fx) * r1[x0] + fx * r1[x1]);
}

// Mip level (fractional) for a footprint of `texels` level-0 texels.
double mipLevel(const Texture& tex, double texels) {
  return std::clamp(std::log2(std::max(texels, 1.0)), 0.0, static_cast<double>(tex.levels.size() - 1));
}

// Trilinear mip-mapped lookup at mip level lambda.
double sampleTexture(const Texture& tex, double a, double b, double lambda) {
  const int last = static_cast<int>(tex.levels.size()) - 1;
  const int l0 = std::min(static_cast<int>(lambda), last);
  const int l1 = std::min(l0 + 1, last);
  const double f = lambda - l0;
  const double v0 = bilinear(tex.levels[static_cast<std::size_t>(l0)], a, b);
  if (f <= 0.0 || l1 == l0) return v0;
  return (1.0 - f) * v0 + f * bilinear(tex.levels[static_cast<std::size_t>(l1)], a, b);
}

}  // namespace

template <>
const ParamSchema<RenderOptions>& paramSchema<RenderOptions>() {
  using O = RenderOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"render", {
      {"supersampling", &O::supersampling, R::closed(1, 4), "", "samples per pixel side"},
      {"image_noise", &O::image_noise, R::closed(0, 50), "grey levels", "Gaussian noise of every pixel"},
      {"near", &O::near, R::closed(0.001, 1), "m", "surfaces closer to the camera are not drawn"},
  }, ParamMessage::kNode};
  return schema;
}

void validate(const RenderOptions& o) { checkRanges(paramSchema<RenderOptions>(), o); }

RenderedView render(const World& world, const PinholeCamera& cam, const Sim3& camera_to_world,
                    const RenderOptions& options, std::uint64_t seed) {
  validate(options);
  if (!cam.valid()) throw InputError("render: invalid camera");
  if (std::abs(camera_to_world.scale() - 1.0) > 1e-9 || !camera_to_world.matrix().allFinite()) {
    throw InputError("render: the camera pose must be a finite rigid transform (scale 1)");
  }
  const std::vector<CameraQuad> quads = cameraQuads(world, cam, camera_to_world, options.near);
  const int ss = options.supersampling;
  const double step = 1.0 / ss;
  const int gw = cam.width * ss;
  RenderedView out;
  out.image = cv::Mat(cam.height, cam.width, CV_8UC1);
  out.depth = cv::Mat(cam.height, cam.width, CV_32FC1);
  out.quad = cv::Mat(cam.height, cam.width, CV_32SC1);
  const double focal = cam.focal();
  std::vector<Eigen::Vector3d> normals(world.quads.size(), Eigen::Vector3d::Zero());  // camera frame
  for (const CameraQuad& q : quads) normals[static_cast<std::size_t>(q.index)] = q.n;
  // Row by row: the z-buffer of one image row's samples, then its shading. Small images (the
  // layout's low-resolution renders) are not worth a thread team.
#pragma omp parallel if (cam.width * cam.height > 20000)
  {
    std::vector<Hit> samples(static_cast<std::size_t>(gw) * static_cast<std::size_t>(ss));
    std::vector<Hit> centres(static_cast<std::size_t>(cam.width));
#pragma omp for schedule(dynamic, 8)
    for (int r = 0; r < cam.height; ++r) {
      // Sub-pixel samples: pixel c covers [c - 0.5, c + 0.5]; sample i sits at c - 0.5 + (i + 0.5) / ss.
      for (int j = 0; j < ss; ++j) {
        rasterizeRow(quads, cam, r - 0.5 + (j + 0.5) * step, -0.5 + 0.5 * step, step, gw, options.near,
                     samples.data() + static_cast<std::size_t>(j) * gw);
      }
      rasterizeRow(quads, cam, r, 0.0, 1.0, cam.width, options.near, centres.data());
      std::mt19937_64 rng(sim_detail::subSeed(seed, static_cast<std::uint64_t>(r)));
      double noise_pair[2] = {0.0, 0.0};
      auto* image_row = out.image.ptr<std::uint8_t>(r);
      auto* depth_row = out.depth.ptr<float>(r);
      auto* quad_row = out.quad.ptr<int>(r);
      for (int c = 0; c < cam.width; ++c) {
        double sum = 0.0;
        int level_quad = -1;  // the mip level is computed once per pixel and surface
        double lambda = 0.0;
        for (int j = 0; j < ss; ++j) {
          for (int i = 0; i < ss; ++i) {
            const Hit& h = samples[static_cast<std::size_t>(j) * gw + static_cast<std::size_t>(c * ss + i)];
            if (h.quad < 0) continue;
            const WorldQuad& wq = world.quads[static_cast<std::size_t>(h.quad)];
            const Texture& tex = world.textures[static_cast<std::size_t>(wq.texture)];
            if (h.quad != level_quad) {
              // Footprint of a sample on the surface [texels]: the sample spacing at depth z,
              // stretched by the obliquity (geometric mean of the two directions).
              const Eigen::Vector3d ray((c - 0.5 + (i + 0.5) * step - cam.cx) / cam.fx,
                                        (r - 0.5 + (j + 0.5) * step - cam.cy) / cam.fy, 1.0);
              const double ray_norm = ray.norm();
              const double cosine =
                  std::max(std::abs(normals[static_cast<std::size_t>(h.quad)].dot(ray)) / ray_norm, 0.05);
              lambda = mipLevel(tex, h.z * ray_norm * step / (focal * std::sqrt(cosine) * tex.texel));
              level_quad = h.quad;
            }
            sum += sampleTexture(tex, h.a, h.b, lambda);
          }
        }
        if (c % 2 == 0 && options.image_noise > 0.0) sim_detail::gaussianPair(rng, &noise_pair[0], &noise_pair[1]);
        const double noise = options.image_noise * noise_pair[c % 2];
        image_row[c] = cv::saturate_cast<std::uint8_t>(sum / (ss * ss) + noise);
        const Hit& centre = centres[static_cast<std::size_t>(c)];
        depth_row[c] = centre.quad >= 0 ? centre.z : 0.0f;
        quad_row[c] = centre.quad;
      }
    }
  }
  return out;
}

}  // namespace pcr_pro
