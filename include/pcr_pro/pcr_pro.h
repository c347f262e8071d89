/**
 * @file pcr_pro.h
 * @brief Umbrella header of the ROS-free pcr_pro core: every stage of the merge, by folder.
 *
 * - geometry/      clouds, similarities, cameras and maps, k-d tree, normals
 * - io/            map bundles, PCD/CSV clouds, the result report, LSD-SLAM keyframes, input limits
 * - frontend/      SIFT/FLANN matching, relative pose, keyframe depth, Kalman-filter scale
 * - registration/  scale detection, filters, ICP, covariance, the cloud registration
 * - merge/         the merge of two agents' maps and the per-agent store
 * - sim/           the synthetic multi-agent world: scene, renderer, LSD-like semi-dense maps, truth
 *
 * @par Error rule (one for every stage)
 * - A caller's mistake throws: invalid options (each options struct's validate(), InputError
 *   naming the field), arguments that contradict each other or the API's stated preconditions
 *   (a k-d tree built for another cloud, a stage object used before it was set up, an empty
 *   cloud given to a building block such as alignIcp() whose header says it must not be
 *   empty), and bad files (InputError naming file and field). The caller can always avoid these.
 * - What the data does returns a Status in the result, with the reason in its message: a map or
 *   cloud that is empty or becomes empty in the filters, no feature matches, no verified pose,
 *   no scale, no overlap, an ICP that does not converge, a degenerate geometry. Data come from
 *   sensors and SLAM systems: a caller cannot rule these out before calling.
 * - The two entry points follow it: registerClouds() and mergeMaps() / MergePipeline::merge()
 *   answer INVALID_INPUT for an empty cloud or map (the same status as when the filters empty
 *   it), and throw only for invalid options (and registerClouds() for a mismatched target_tree).
 * - Out of memory is std::bad_alloc, as everywhere in C++. The tools turn every exception into
 *   exit status 2 with one line; the ROS node answers every merge with a status code.
 */
#pragma once

#include "pcr_pro/frontend/feature_matching.h"
#include "pcr_pro/frontend/keyframe_depth.h"
#include "pcr_pro/frontend/relative_pose.h"
#include "pcr_pro/frontend/scale_estimation.h"
#include "pcr_pro/geometry/kdtree.h"
#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/geometry/normals.h"
#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/geometry/types.h"
#include "pcr_pro/io/bundle.h"
#include "pcr_pro/io/bundle_writer.h"
#include "pcr_pro/io/cloud_io.h"
#include "pcr_pro/io/input_limits.h"
#include "pcr_pro/io/lsd_keyframe.h"
#include "pcr_pro/io/report.h"
#include "pcr_pro/merge/agent_store.h"
#include "pcr_pro/merge/merge_pipeline.h"
#include "pcr_pro/registration/cloud_registration.h"
#include "pcr_pro/registration/config.h"
#include "pcr_pro/registration/covariance.h"
#include "pcr_pro/registration/filters.h"
#include "pcr_pro/registration/icp.h"
#include "pcr_pro/registration/scale_detection.h"
#include "pcr_pro/sim/render.h"
#include "pcr_pro/sim/semi_dense.h"
#include "pcr_pro/sim/simulator.h"
#include "pcr_pro/sim/world.h"
