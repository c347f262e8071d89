#include "pcr_pro/sim/world.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <sstream>

#include "sim/sim_random.h"

namespace pcr_pro {
namespace {

using sim_detail::gaussian;
using sim_detail::subSeed;
using sim_detail::uniform;
using sim_detail::uniform01;
using sim_detail::uniformInt;

std::string num(double v) { return schema_detail::numberText(v); }

// A bound computed from other fields, to 6 digits (2.7, not the sum's 2.6999999999999997).
std::string bound(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

// A range that depends on another field ("<limit>" names it): the schemas hold the fixed ones.
void checkAtLeast(const std::string& key, double v, double lo, const std::string& limit) {
  if (!(v >= lo)) throw InputError("world." + key + ": must be >= " + limit + " = " + bound(lo) + ", got " + num(v));
}
void checkAtMost(const std::string& key, double v, double hi, const std::string& limit) {
  if (!(v <= hi)) throw InputError("world." + key + ": must be <= " + limit + " = " + bound(hi) + ", got " + num(v));
}

// Fixed-point shift of OpenCV's drawing functions: 4 bits of sub-texel position.
constexpr int kShift = 4;
constexpr double kSub = 16.0;

cv::Point fixedPoint(double x, double y) {
  return cv::Point(static_cast<int>(std::lround(x * kSub)), static_cast<int>(std::lround(y * kSub)));
}

// One random shape of about `size` texels centred at (x, y).
void drawShape(cv::Mat* img, double x, double y, double size, std::mt19937_64& rng) {
  const double grey = uniform(rng, 0.0, 255.0);
  const cv::Scalar colour(grey);
  const int type = uniformInt(rng, 0, 9);
  const double angle = uniform(rng, 0.0, 2.0 * M_PI);
  if (type <= 2) {  // ellipse (filled, or a ring)
    const double a = 0.5 * size * uniform(rng, 0.4, 1.0), b = 0.5 * size * uniform(rng, 0.25, 1.0);
    const int thickness = type == 2 ? std::max(1, static_cast<int>(0.15 * size)) : cv::FILLED;
    cv::ellipse(*img, fixedPoint(x, y), cv::Size(static_cast<int>(a * kSub), static_cast<int>(b * kSub)),
                angle * 180.0 / M_PI, 0.0, 360.0, colour, thickness, cv::LINE_AA, kShift);
  } else if (type <= 6) {  // convex polygon with 3 to 6 corners (rectangles included)
    const int corners = type == 3 ? 4 : uniformInt(rng, 3, 6);
    std::vector<cv::Point> pts;
    for (int k = 0; k < corners; ++k) {
      const double phi = angle + 2.0 * M_PI * (k + uniform(rng, -0.3, 0.3)) / corners;
      const double r = 0.5 * size * uniform(rng, 0.6, 1.0);
      pts.push_back(fixedPoint(x + r * std::cos(phi), y + r * std::sin(phi)));
    }
    cv::fillConvexPoly(*img, pts, colour, cv::LINE_AA, kShift);
  } else {  // stroke: a short random polyline
    std::vector<cv::Point> pts;
    double px = x, py = y, dir = angle;
    const int segments = uniformInt(rng, 2, 5);
    for (int k = 0; k <= segments; ++k) {
      pts.push_back(fixedPoint(px, py));
      dir += uniform(rng, -1.2, 1.2);
      px += 0.35 * size * std::cos(dir);
      py += 0.35 * size * std::sin(dir);
    }
    const int thickness = std::max(1, static_cast<int>(size * uniform(rng, 0.06, 0.18)));
    cv::polylines(*img, pts, false, colour, thickness, cv::LINE_AA, kShift);
  }
}

// Irradiance of a face (one value per `step` texels), from two point lights and an ambient term.
cv::Mat shading(const WorldQuad& quad, cv::Size size, const std::vector<Eigen::Vector3d>& lights, double ambient) {
  constexpr int kStep = 8;
  const int w = std::max(2, size.width / kStep + 2), h = std::max(2, size.height / kStep + 2);
  cv::Mat coarse(h, w, CV_32FC1);
  const Eigen::Vector3d n = quad.normal();
  for (int r = 0; r < h; ++r) {
    for (int c = 0; c < w; ++c) {
      const double a = std::min(1.0, static_cast<double>(c) / (w - 1));
      const double b = std::min(1.0, static_cast<double>(r) / (h - 1));
      const Eigen::Vector3d p = quad.origin + a * quad.axis_u + b * quad.axis_v;
      double direct = 0.0;
      for (const Eigen::Vector3d& l : lights) {
        const Eigen::Vector3d d = l - p;
        const double dist2 = d.squaredNorm();
        // Lambert's cosine law and a softened inverse-square fall-off (range about 4 m).
        direct += std::max(0.0, n.dot(d) / std::sqrt(dist2)) * 16.0 / (16.0 + dist2);
      }
      coarse.at<float>(r, c) = static_cast<float>(ambient + (1.0 - ambient) * std::min(1.0, 0.75 * direct));
    }
  }
  cv::Mat fine;
  cv::resize(coarse, fine, size, 0.0, 0.0, cv::INTER_LINEAR);
  return fine;
}

Texture makeTexture(const cv::Mat& image, double texel) {
  Texture t;
  t.texel = texel;
  cv::Mat level;
  image.convertTo(level, CV_32FC1);
  t.levels.push_back(level);
  while (std::min(level.cols, level.rows) >= 8) {
    cv::Mat next;
    cv::pyrDown(level, next);
    t.levels.push_back(next);
    level = next;
  }
  return t;
}

void addLitQuad(World* world, WorldQuad quad, const WorldOptions& o, const std::vector<Eigen::Vector3d>& lights,
                std::uint64_t seed) {
  const cv::Mat albedo = proceduralTexture(quad.axis_u.norm(), quad.axis_v.norm(), o.texture, seed);
  const cv::Mat light = shading(quad, albedo.size(), lights, o.ambient);
  cv::Mat lit;
  cv::multiply(albedo, light, lit);
  quad.texture = static_cast<int>(world->textures.size());
  world->textures.push_back(makeTexture(lit, o.texture.texel));
  world->quads.push_back(std::move(quad));
}

// Five faces of a box (no bottom), normals pointing out.
void addBox(World* world, const WorldBox& box, int index, const WorldOptions& o,
            const std::vector<Eigen::Vector3d>& lights, std::uint64_t seed) {
  const Eigen::Vector3d& lo = box.min;
  const Eigen::Vector3d e = box.max - box.min;
  const Eigen::Vector3d x(e.x(), 0, 0), y(0, e.y(), 0), z(0, 0, e.z());
  const std::string name = "box_" + std::to_string(index) + "_";
  // Outward normals; side faces with a horizontal first axis (texture rows run along image rows
  // for a level camera: cache-friendly lookups).
  const std::vector<WorldQuad> faces{
      {lo + z, x, y, 0, name + "top"},
      {lo, x, z, 0, name + "y-"},
      {lo + x + y, -x, z, 0, name + "y+"},
      {lo + y, -y, z, 0, name + "x-"},
      {lo + x, y, z, 0, name + "x+"},
  };
  int k = 0;
  for (const WorldQuad& f : faces) {
    addLitQuad(world, f, o, lights, subSeed(seed, static_cast<std::uint64_t>(k++)));
  }
}

bool boxesIntersect(const WorldBox& a, const WorldBox& b, double gap) {
  for (int i = 0; i < 2; ++i) {  // horizontal extents only: boxes stand on the floor
    if (a.max[i] + gap <= b.min[i] || b.max[i] + gap <= a.min[i]) return false;
  }
  return true;
}

// A random box against a wall or free-standing; false when it does not fit.
bool randomBox(const WorldOptions& o, std::mt19937_64& rng, WorldBox* box) {
  const double hx = 0.5 * o.room_length, hy = 0.5 * o.room_width;
  const bool against_wall = uniform01(rng) < 0.7;
  const double width = uniform(rng, 0.4, 1.6);
  const double depth = uniform(rng, 0.25, o.max_box_depth);
  const double height = against_wall ? uniform(rng, 0.4, o.max_wall_box_height) : uniform(rng, 0.35, o.max_free_box_height);
  Eigen::Vector2d centre, half;
  if (against_wall) {
    const int wall = uniformInt(rng, 0, 3);
    const bool along_x = wall < 2;  // walls y = -hy / +hy run along x
    const double span = (along_x ? hx : hy) - 0.5 * width - 0.05;
    if (span <= 0.0) return false;
    const double s = uniform(rng, -span, span);
    const double sign = wall % 2 ? 1.0 : -1.0;
    const double off = 0.5 * depth + 0.02;  // a 2 cm gap to the wall
    if (along_x) {
      centre = {s, sign * (hy - off)};
      half = {0.5 * width, 0.5 * depth};
    } else {
      centre = {sign * (hx - off), s};
      half = {0.5 * depth, 0.5 * width};
    }
  } else {
    const double mx = hx - o.free_box_wall_distance - 0.5 * width, my = hy - o.free_box_wall_distance - 0.5 * width;
    if (mx <= 0.0 || my <= 0.0) return false;
    centre = {uniform(rng, -mx, mx), uniform(rng, -my, my)};
    half = {0.5 * width, 0.5 * depth};
    if (uniform01(rng) < 0.5) std::swap(half.x(), half.y());
  }
  box->min = Eigen::Vector3d(centre.x() - half.x(), centre.y() - half.y(), 0.0);
  box->max = Eigen::Vector3d(centre.x() + half.x(), centre.y() + half.y(), height);
  return true;
}

}  // namespace

template <>
const ParamSchema<WorldOptions>& paramSchema<WorldOptions>() {
  using O = WorldOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"world", {
      {"room_length", &O::room_length, R::closed(2, 100), "m", "interior extent along x"},
      {"room_width", &O::room_width, R::closed(2, 100), "m", "interior extent along y"},
      {"room_height", &O::room_height, R::closed(2, 20), "m", "interior height"},
      {"boxes", &O::boxes, R::closed(0, 100), "", "number of furniture-like boxes"},
      {"max_box_depth", &O::max_box_depth, R::closed(0.25, 2), "m", "depth of a box against a wall"},
      {"max_wall_box_height", &O::max_wall_box_height, R::atLeast(0.4), "m",
       "height of a box against a wall (also <= room_height - 0.1)"},
      {"max_free_box_height", &O::max_free_box_height, R::atLeast(0.35), "m",
       "height of a free-standing box (also <= room_height - 0.1)"},
      {"free_box_wall_distance", &O::free_box_wall_distance, R::closed(0, 50), "m",
       "smallest distance of a free-standing box from the walls"},
      {"ambient", &O::ambient, R::closed(0, 1), "-", "ambient share of the lighting"},
  }, ParamMessage::kNode};
  return schema;
}

template <>
const ParamSchema<TextureOptions>& paramSchema<TextureOptions>() {
  using O = TextureOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"world.texture", {
      {"texel", &O::texel, R::closed(0.001, 0.05), "m", "texel size"},
      {"min_shape_size", &O::min_shape_size, R::openClosed(0, 10), "m", "smallest shape drawn (also >= 2 texel)"},
      {"max_shape_size", &O::max_shape_size, R::openClosed(0, 10), "m", "largest shape drawn (also >= min_shape_size)"},
      {"coverage", &O::coverage, R::closed(1e-3, 5), "-", "fraction of a face the largest shapes cover"},
      {"detail_decay", &O::detail_decay, R::closed(1e-3, 1), "-", "coverage ratio of one size octave to the next"},
      {"blur", &O::blur, R::closed(0, 5), "texels", "Gaussian blur of the drawn texture"},
  }, ParamMessage::kNode};
  return schema;
}

void validate(const WorldOptions& o) {
  checkRanges(paramSchema<WorldOptions>(), o);
  checkRanges(paramSchema<TextureOptions>(), o.texture);
  // The boxes stay 10 cm below the ceiling; a shape spans at least two texels.
  checkAtMost("max_wall_box_height", o.max_wall_box_height, o.room_height - 0.1, "room_height - 0.1");
  checkAtMost("max_free_box_height", o.max_free_box_height, o.room_height - 0.1, "room_height - 0.1");
  checkAtLeast("texture.min_shape_size", o.texture.min_shape_size, 2.0 * o.texture.texel, "2 texture.texel");
  checkAtLeast("texture.max_shape_size", o.texture.max_shape_size, o.texture.min_shape_size, "texture.min_shape_size");
  // A texture beyond 2^28 texels (e.g. a 100 m room with 1 mm texels) would not fit in memory.
  const double side = std::max({o.room_length, o.room_width, o.room_height});
  if (side * side / (o.texture.texel * o.texture.texel) > 268435456.0) {
    throw InputError("world.texture.texel: " + num(o.texture.texel) + " m is too fine for a " + num(side) +
                     " m room (more than 2^28 texels per face)");
  }
}

bool World::isFree(const Eigen::Vector3d& p, double margin) const {
  for (int i = 0; i < 3; ++i) {
    if (p[i] < room_min[i] + margin || p[i] > room_max[i] - margin) return false;
  }
  for (const WorldBox& b : boxes) {
    bool inside = true;
    for (int i = 0; i < 3; ++i) inside = inside && p[i] > b.min[i] - margin && p[i] < b.max[i] + margin;
    if (inside) return false;
  }
  return true;
}

cv::Mat proceduralTexture(double width_m, double height_m, const TextureOptions& o, std::uint64_t seed) {
  const int w = std::max(4, static_cast<int>(std::ceil(width_m / o.texel)));
  const int h = std::max(4, static_cast<int>(std::ceil(height_m / o.texel)));
  std::mt19937_64 rng(seed);
  // Background: a random grey with a smooth variation (a coarse random grid, cubic upsampling).
  const double cell = 0.4 / o.texel;  // 40 cm
  cv::Mat coarse(std::max(2, static_cast<int>(h / cell) + 2), std::max(2, static_cast<int>(w / cell) + 2), CV_32FC1);
  const double base = uniform(rng, 80.0, 180.0);
  for (int r = 0; r < coarse.rows; ++r) {
    for (int c = 0; c < coarse.cols; ++c) coarse.at<float>(r, c) = static_cast<float>(base + 25.0 * gaussian(rng));
  }
  cv::Mat background;
  cv::resize(coarse, background, cv::Size(w, h), 0.0, 0.0, cv::INTER_CUBIC);
  cv::Mat img;
  background.convertTo(img, CV_8UC1);
  // Shapes, largest first, so that small ones lie on top of large ones as details do.
  const double area = static_cast<double>(w) * h;
  double coverage = o.coverage;
  for (double size_m = o.max_shape_size; size_m >= o.min_shape_size * 0.999; size_m *= 0.5, coverage *= o.detail_decay) {
    const double size = size_m / o.texel;
    const double count = coverage * area / (size * size);
    const auto n = static_cast<long>(count) + (uniform01(rng) < count - std::floor(count) ? 1 : 0);
    for (long k = 0; k < n; ++k) {
      const double s = size * uniform(rng, 0.7, 1.4);
      drawShape(&img, uniform(rng, -0.5 * s, w + 0.5 * s), uniform(rng, -0.5 * s, h + 0.5 * s), s, rng);
    }
  }
  cv::Mat out;
  img.convertTo(out, CV_32FC1);
  if (o.blur > 0.0) cv::GaussianBlur(out, out, cv::Size(0, 0), o.blur);
  return out;
}

void addTexturedQuad(World* world, WorldQuad quad, const cv::Mat& image, double texel) {
  if (image.empty() || (image.type() != CV_8UC1 && image.type() != CV_32FC1)) {
    throw InputError("addTexturedQuad: image must be a non-empty CV_8UC1 or CV_32FC1 image");
  }
  const double nu = quad.axis_u.norm(), nv = quad.axis_v.norm();
  if (!(nu > 0.0 && nv > 0.0) || std::abs(quad.axis_u.dot(quad.axis_v)) > 1e-9 * nu * nv) {
    throw InputError("addTexturedQuad: quad " + quad.name + ": axes must be non-zero and orthogonal");
  }
  quad.texture = static_cast<int>(world->textures.size());
  world->textures.push_back(makeTexture(image, texel));
  world->quads.push_back(std::move(quad));
}

World makeRoomWorld(const WorldOptions& o, std::uint64_t seed) {
  validate(o);
  World world;
  const double hx = 0.5 * o.room_length, hy = 0.5 * o.room_width, hz = o.room_height;
  world.room_min = Eigen::Vector3d(-hx, -hy, 0.0);
  world.room_max = Eigen::Vector3d(hx, hy, hz);
  std::mt19937_64 rng(subSeed(seed, 0));
  // Two lights 20 cm under the ceiling, somewhere in the middle half of the room.
  std::vector<Eigen::Vector3d> lights;
  for (int k = 0; k < 2; ++k) {
    lights.emplace_back(uniform(rng, -0.5 * hx, 0.5 * hx), uniform(rng, -0.5 * hy, 0.5 * hy), hz - 0.2);
  }
  // Room faces, normals pointing into the room; walls with a horizontal first axis.
  const Eigen::Vector3d lx(o.room_length, 0, 0), ly(0, o.room_width, 0), lz(0, 0, hz);
  const Eigen::Vector3d c000(-hx, -hy, 0.0);
  const std::vector<WorldQuad> room{
      {c000, lx, ly, 0, "floor"},
      {c000 + lz, ly, lx, 0, "ceiling"},
      {c000 + lx, -lx, lz, 0, "wall_y-"},
      {c000 + ly, lx, lz, 0, "wall_y+"},
      {c000, ly, lz, 0, "wall_x-"},
      {c000 + lx + ly, -ly, lz, 0, "wall_x+"},
  };
  std::uint64_t face = 0;
  for (const WorldQuad& q : room) addLitQuad(&world, q, o, lights, subSeed(seed, 100 + face++));
  // Furniture: rejection sampling of non-intersecting boxes.
  for (int attempt = 0; static_cast<int>(world.boxes.size()) < o.boxes; ++attempt) {
    if (attempt > 200 * (o.boxes + 1)) {
      throw InputError("world.boxes: " + std::to_string(o.boxes) + " boxes do not fit in a " + num(o.room_length) + " x " +
                       num(o.room_width) + " m room");
    }
    WorldBox box;
    if (!randomBox(o, rng, &box)) continue;
    bool free = true;
    for (const WorldBox& other : world.boxes) free = free && !boxesIntersect(box, other, 0.1);
    if (!free) continue;
    addBox(&world, box, static_cast<int>(world.boxes.size()), o, lights, subSeed(seed, 1000 + 10 * world.boxes.size()));
    world.boxes.push_back(box);
  }
  return world;
}

}  // namespace pcr_pro
