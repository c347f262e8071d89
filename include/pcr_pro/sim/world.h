/**
 * @file world.h
 * @brief The simulator's scene: textured planar rectangles (a room's floor, ceiling and walls,
 * furniture-like boxes), each with its own procedural texture (random shapes at several scales
 * on a smoothly varying background, lit by point lights), generated from a seed. World frame:
 * metres, z up, origin at the centre of the room's floor.
 */
#pragma once

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include <cstdint>
#include <string>
#include <vector>

#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/param_schema.h"

namespace pcr_pro {

/// How the procedural textures are drawn (YAML block `world.texture`).
struct TextureOptions {
  /// Texel size [m], in [0.001, 0.05]. A camera 1.5 m away with a 525 px focal length sees
  /// 2.9 mm per pixel: 5 mm texels are magnified less than 2x there.
  double texel = 0.005;
  /// Smallest shape drawn [m], in (0, 10] and >= 2 texel; SIFT at 640x480 finds blobs of about
  /// 4 px and more, which is 1.5 cm at 2 m.
  double min_shape_size = 0.015;
  /// Largest shape drawn [m], in (0, 10] and >= min_shape_size.
  double max_shape_size = 0.6;
  /// Fraction of a face that the shapes of the largest size octave cover (they overlap) [-],
  /// in [0.001, 5]; each smaller octave covers detail_decay times that of the octave above, so
  /// that fine detail is sprinkled over larger shapes instead of making the face a uniform grain.
  double coverage = 0.8;
  /// Coverage ratio of one size octave to the next larger one [-], in [0.001, 1].
  double detail_decay = 0.6;
  /// Gaussian blur of the drawn texture, a band limit against aliasing [texels], in [0, 5].
  double blur = 0.7;
};

/// The room and its furniture (YAML block `world`).
struct WorldOptions {
  double room_length = 7.0;  ///< interior extent along x [m], in [2, 100]
  double room_width = 5.0;   ///< interior extent along y [m], in [2, 100]
  double room_height = 2.8;  ///< interior height [m], in [2, 20]
  /// Number of furniture-like boxes [-], in [0, 100]. Boxes against a wall are at most
  /// max_wall_box_height high and max_box_depth deep; boxes away from the walls are at most
  /// max_free_box_height high (a camera above that height never hits them).
  int boxes = 8;
  /// The lower ends below are those of the uniform draws (a box is 0.25 m to max_box_depth deep,
  /// 0.4 m to max_wall_box_height or 0.35 m to max_free_box_height high), so a maximum below them
  /// would make an empty interval.
  double max_box_depth = 0.7;        ///< [m], in [0.25, 2]
  double max_wall_box_height = 2.0;  ///< [m], >= 0.4 and <= room_height - 0.1
  double max_free_box_height = 1.0;  ///< [m], >= 0.35 and <= room_height - 0.1
  /// Smallest distance of a free-standing box from the walls [m], in [0, 50].
  double free_box_wall_distance = 1.6;
  /// Ambient share of the lighting [-], in [0, 1]; the rest comes from two point lights near
  /// the ceiling (Lambertian, view-independent, so that every camera sees the same shading).
  double ambient = 0.4;
  TextureOptions texture;
};

/// @throw InputError naming the option ("world.room_length: must be in [2, 100], got 1")
void validate(const WorldOptions& options);

/// The schemas of the blocks `world` and `world.texture` (per-field ranges; validate() adds the
/// ones that depend on other fields).
template <>
const ParamSchema<WorldOptions>& paramSchema<WorldOptions>();
template <>
const ParamSchema<TextureOptions>& paramSchema<TextureOptions>();

/// A texture with its mip pyramid.
struct Texture {
  /// CV_32FC1 grey levels [0, 255]; levels[0] has one texel per `texel`, each next level half
  /// the size (Gaussian pyramid), down to a side of 4 texels.
  std::vector<cv::Mat> levels;
  double texel = 0.005;  ///< size of a level-0 texel [m]
};

/// A textured rectangle: the points origin + a * axis_u + b * axis_v, a and b in [0, 1].
/// Texture column = a * width, row = b * height (level 0).
struct WorldQuad {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();  ///< a corner [m]
  Eigen::Vector3d axis_u = Eigen::Vector3d::UnitX();  ///< first edge [m]
  Eigen::Vector3d axis_v = Eigen::Vector3d::UnitY();  ///< second edge, orthogonal to axis_u [m]
  int texture = 0;                                     ///< index into World::textures
  std::string name;                                    ///< e.g. "wall_x+", "box_3_top"
  /// @return unit normal axis_u x axis_v (the lit side)
  Eigen::Vector3d normal() const { return axis_u.cross(axis_v).normalized(); }
};

/// An axis-aligned box of furniture [m].
struct WorldBox {
  Eigen::Vector3d min = Eigen::Vector3d::Zero();
  Eigen::Vector3d max = Eigen::Vector3d::Zero();
};

/// The scene.
struct World {
  std::vector<WorldQuad> quads;
  std::vector<Texture> textures;
  Eigen::Vector3d room_min = Eigen::Vector3d::Zero();  ///< interior corner [m]
  Eigen::Vector3d room_max = Eigen::Vector3d::Zero();  ///< interior corner [m]
  std::vector<WorldBox> boxes;

  /// @return true when p is inside the room and outside every box, at least margin [m] from both
  bool isFree(const Eigen::Vector3d& p, double margin) const;
};

/**
 * @brief A room: floor, ceiling and four walls, and furniture boxes (five faces each, no
 * bottom) that do not intersect; every face gets its own texture. Deterministic from the seed.
 * @param[in] options room and texture options
 * @param[in] seed random seed
 * @throw InputError on invalid options, or when the boxes do not fit in the room
 */
World makeRoomWorld(const WorldOptions& options, std::uint64_t seed);

/**
 * @brief Adds a quad with a texture of its own made from an image (no lighting applied), e.g.
 * a test pattern. Texture column / row = a * image.cols / b * image.rows.
 * @param[in,out] world the world
 * @param[in] quad geometry and name (quad.texture is set here)
 * @param[in] image CV_8UC1 or CV_32FC1 grey levels [0, 255]
 * @param[in] texel size of one image pixel on the quad [m]; must match |axis_u| / cols
 * @throw InputError on an empty image or non-orthogonal / zero axes
 */
void addTexturedQuad(World* world, WorldQuad quad, const cv::Mat& image, double texel);

/**
 * @brief A procedural albedo image: a smooth background and random filled ellipses, polygons,
 * rectangles and strokes of random grey at every size octave from max_shape_size down to
 * min_shape_size, band-limited by a Gaussian blur.
 * @param[in] width_m, height_m extent [m]
 * @param[in] options texture options
 * @param[in] seed random seed
 * @return CV_32FC1 grey levels in [0, 255], one pixel per options.texel
 */
cv::Mat proceduralTexture(double width_m, double height_m, const TextureOptions& options, std::uint64_t seed);

}  // namespace pcr_pro
