// The projective registration's options: schema and validation, apart from the stage itself so
// that the configuration readers (and their fuzz target) do not link the registration.
#include "pcr_pro/registration/projective_registration.h"

namespace pcr_pro {

template <>
const ParamSchema<ProjectiveOptions>& paramSchema<ProjectiveOptions>() {
  using O = ProjectiveOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"projective", {
      {"edge_stddev_px", &O::edge_stddev_px, R::above(0), "px", "standard deviation of an edge's position across it"},
      {"search_radius_px", &O::search_radius_px, R::closed(0, 5), "px",
       "a projected point is matched with the likeliest pixel with depth within this radius"},
      {"max_relative_stddev", &O::max_relative_stddev, R::open(0, 1), "-",
       "pixels whose depth claims a larger relative standard deviation are not used"},
      {"pixel_step", &O::pixel_step, R::atLeast(1), "", "every n-th usable pixel of the moving map becomes a point"},
      {"max_iterations", &O::max_iterations, R::atLeast(1), "", "Gauss-Newton iterations at most"},
      {"kernel_width", &O::kernel_width, R::above(0), "-", "Cauchy kernel width in robust spreads"},
      {"extrapolation", &O::extrapolation, R::any(), "", "take the rest of a creeping series of steps at once"},
      {"depth_disagreement", &O::depth_disagreement, R::any(), "",
       "estimate the two maps' relative depth disagreement beyond their per-pixel noise and weigh the depth by it"},
      {"photometric", &O::photometric, R::any(), "",
       "also compare each moving point's grey level with the other keyframes' images where it projects"},
      {"photometric_blur_px", &O::photometric_blur_px, R::atLeast(0), "px",
       "standard deviation of the Gaussian that smooths the images before their grey levels are compared"},
      {"jackknife", &O::jackknife, R::any(), "",
       "the covariance adds the estimate's spread when each keyframe is left out in turn"},
      {"jackknife_point_step", &O::jackknife_point_step, R::atLeast(1), "",
       "the jackknife's leave-outs use every n-th of the moving points"},
      {"direction_spread", &O::direction_spread, R::any(), "",
       "the covariance adds the difference between the two directions' estimates as a spread"},
  }};
  return schema;
}

void validate(const ProjectiveOptions& options) { checkRanges(paramSchema<ProjectiveOptions>(), options); }

}  // namespace pcr_pro
