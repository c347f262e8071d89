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
