/**
 * @file pose_graph.h
 * @brief Export of a merge as a pose graph: every keyframe of both agents as a g2o
 * `VERTEX_SIM3:EXPMAP` in the target map frame, the merge's edge as an `EDGE_SIM3:EXPMAP` between
 * its anchor keyframes with its 7x7 information; and a TUM trajectory of the fused keyframes.
 *
 * g2o's conventions (types_seven_dof_expmap, sim3.h of g2o's `types/sim3`), which this file follows:
 *  - a Sim(3) tangent vector is (ω, υ, σ): rotation vector, the translation part of the Lie algebra
 *    (t = W(ω, σ) υ, not t itself) and the log of the scale; exp / log are the group's own;
 *  - a vertex's estimate is the world -> camera similarity; its line holds log(camera -> world)
 *    (7 numbers), then fx fy cx cy of the camera;
 *  - an edge i -> j measures C = S_j ∘ S_i⁻¹ (the error is log(C ∘ S_i ∘ S_j⁻¹), a left
 *    perturbation of C); its line holds log(C⁻¹), then the upper triangle of the 7x7 information
 *    row by row, in the tangent order (ω, υ, σ).
 * pcr_pro's own covariance order is (x y z, rx ry rz, σ) (similarity_fit.h); the export reorders it.
 */
#pragma once

#include <Eigen/Core>

#include <string>
#include <vector>

#include "pcr_pro/geometry/map_types.h"
#include "pcr_pro/geometry/sim3.h"
#include "pcr_pro/geometry/types.h"

namespace pcr_pro {

/// A g2o Sim(3) tangent vector (ω, υ, σ).
using G2oTangent = Eigen::Matrix<double, 7, 1>;

/// @return g2o's Sim(3) exponential of (ω, υ, σ) [rad, target units, -]
Sim3 g2oSim3Exp(const G2oTangent& tangent);
/// @return g2o's Sim(3) logarithm (ω, υ, σ), |ω| <= π; the inverse of g2oSim3Exp()
G2oTangent g2oSim3Log(const Sim3& s);

/// One keyframe of the exported graph.
struct PoseGraphVertex {
  int id = 0;                  ///< g2o vertex id (target keyframes first, then the source's)
  std::string agent;           ///< the agent's name (no white space)
  long keyframe = 0;           ///< the keyframe id in its agent
  Sim3 camera_to_world;        ///< camera -> target map similarity
  double fx = 1.0, fy = 1.0;   ///< focal lengths [px]
  double cx = 0.0, cy = 0.0;   ///< principal point [px]
};

/// One g2o `EDGE_SIM3:EXPMAP` from vertex `from` (i) to vertex `to` (j).
struct PoseGraphEdge {
  int from = 0, to = 0;
  Sim3 measurement;                           ///< C = S_j ∘ S_i⁻¹ (world -> camera estimates S)
  Matrix7d information = Matrix7d::Identity();  ///< in g2o's tangent order (ω, υ, σ)
};

/// A pose graph as written to / read from a g2o file.
struct PoseGraph {
  std::vector<PoseGraphVertex> vertices;
  std::vector<PoseGraphEdge> edges;
  std::vector<int> fixed;  ///< vertex ids held fixed (`FIX`): the target's first keyframe
};

/// The merge's edge as the export needs it.
struct MergeEdge {
  Sim3 target_from_source;                  ///< S_target_source
  Matrix7d covariance = Matrix7d::Zero();   ///< left perturbation, order (x y z rx ry rz σ) (similarity_fit.h)
  long source_keyframe = 0;                 ///< the anchor keyframe pair the edge belongs to
  long target_keyframe = 0;
};

/**
 * @brief The pose graph of one merge: every keyframe of the target (camera -> target map as it is)
 * and of the source (mapped by S_target_source), and the merge's edge between the anchor keyframes
 * with the covariance carried into g2o's convention (adjoint of (S_target_source ∘ P_source)⁻¹,
 * reordered) and inverted.
 * @param[in] target, source the two maps (their cameras and keyframe poses)
 * @param[in] target_name, source_name agent names written beside the vertices (white space becomes '_')
 * @param[in] edge the merge's edge
 * @return the graph, the target's first keyframe fixed
 * @throw InputError when an anchor keyframe is missing from its map, a map has no keyframe, or the
 *   covariance is not finite and positive definite (a caller's mistake: export successful merges)
 */
PoseGraph mergePoseGraph(const AgentMap& target, const std::string& target_name, const AgentMap& source,
                         const std::string& source_name, const MergeEdge& edge);

/**
 * @brief The covariance of the edge measurement C = (S_ts ∘ P_s)⁻¹ ∘ P_t in g2o's tangent order,
 * from that of S_target_source (left perturbation, pcr_pro order) [target units², rad², -].
 */
Matrix7d g2oEdgeCovariance(const MergeEdge& edge, const Sim3& source_pose);

/// @return the graph as g2o text: comment lines naming each vertex's agent and keyframe, then
/// VERTEX_SIM3:EXPMAP, EDGE_SIM3:EXPMAP and FIX lines (17 significant digits)
std::string toG2o(const PoseGraph& graph);

/**
 * @brief Reads a g2o file of VERTEX_SIM3:EXPMAP / EDGE_SIM3:EXPMAP / FIX lines (and the
 * comments toG2o() writes, which give agent and keyframe; other comments are skipped).
 * @param[in] text the file's content
 * @param[in] origin file name for messages
 * @throw InputError "<origin>: line N: <what>" on an unknown tag, a missing or non-finite number,
 *   a duplicate vertex id, an edge or FIX naming an unknown vertex
 */
PoseGraph parseG2o(const std::string& text, const std::string& origin);

/**
 * @brief The fused keyframes as a TUM trajectory: one line `timestamp tx ty tz qx qy qz qw` per
 * vertex (camera position and orientation in the target map; the timestamp is the keyframe id, as
 * the maps carry no times), each agent's block after a comment line naming it. TUM has no scale:
 * a pose's scale is not written.
 */
std::string toTum(const PoseGraph& graph);

/// @brief Writes text to a file through a temporary file renamed into place (a reader never sees
/// half a file). @throw InputError naming the file when it cannot be written
void writeTextFileAtomically(const std::string& path, const std::string& text);

}  // namespace pcr_pro
