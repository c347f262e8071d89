/**
 * @file render.h
 * @brief Renders the grey image and the depth image of a pinhole camera in a World: a z-buffer
 * over the textured quads, supersampled, with mip-mapped trilinear texture lookups (no
 * aliasing of the texture detail) and Gaussian sensor noise. Pixel (c, r) is centred at image
 * coordinates (c, r), as in OpenCV and the pinhole model of PinholeCamera::project().
 */
#pragma once

#include <opencv2/core.hpp>

#include <cstdint>

#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/io/param_schema.h"
#include "pcr_pro/sim/world.h"

namespace pcr_pro {

/// Rendering options (YAML block `render`).
struct RenderOptions {
  /// Samples per pixel side [-], in [1, 4]: the grey value of a pixel is the mean of
  /// supersampling² samples on a regular grid inside it.
  int supersampling = 2;
  /// Standard deviation of the Gaussian noise added to every pixel [grey levels], in [0, 50].
  double image_noise = 1.5;
  /// Surfaces closer to the camera than this are not drawn [m], in [0.001, 1].
  double near = 0.05;
};

/// @throw InputError naming the option ("render.supersampling: must be in [1, 4], got 0")
void validate(const RenderOptions& options);

/// The schema of the block `render`.
template <>
const ParamSchema<RenderOptions>& paramSchema<RenderOptions>();

/// What render() returns.
struct RenderedView {
  cv::Mat image;  ///< CV_8UC1 grey image
  /// CV_32FC1 depth along the optical axis of the surface at each pixel centre [m]; 0 = none
  cv::Mat depth;
  /// CV_32SC1 index into World::quads of the surface at each pixel centre; -1 = none
  cv::Mat quad;
};

/**
 * @brief Renders a view.
 * @param[in] world the scene
 * @param[in] camera intrinsics and image size
 * @param[in] camera_to_world rigid camera -> world pose (scale 1) [m]
 * @param[in] options rendering options
 * @param[in] seed seed of the sensor noise: equal inputs give equal images
 * @throw InputError on invalid options or camera, or a pose with a scale other than 1
 */
RenderedView render(const World& world, const PinholeCamera& camera, const Sim3& camera_to_world,
                    const RenderOptions& options, std::uint64_t seed);

}  // namespace pcr_pro
