#include "pcr_pro/io/report.h"

#include <iomanip>
#include <sstream>

namespace pcr_pro {
namespace {

std::string quoted(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    if (c == '\n') {
      out += "\\n";
      continue;
    }
    out += c;
  }
  return out + "\"";
}

template <typename M>
void writeMatrix(std::ostream& os, const char* key, const M& m) {
  os << key << ": [";
  for (int r = 0; r < m.rows(); ++r) {
    for (int c = 0; c < m.cols(); ++c) os << (r || c ? ", " : "") << m(r, c);
  }
  os << "]\n";
}

}  // namespace

std::string toYaml(const RegistrationReport& r) {
  std::ostringstream os;
  os << std::setprecision(10);
  os << "status: " << statusName(r.status) << "\n";
  os << "message: " << quoted(r.message) << "\n";
  if (r.source_keyframe) os << "source_keyframe: " << *r.source_keyframe << "\n";
  if (r.target_keyframe) os << "target_keyframe: " << *r.target_keyframe << "\n";
  if (r.transform) {
    const Eigen::Quaterniond q = r.transform->quaternion();
    const Eigen::Vector3d& t = r.transform->translation();
    os << "scale: " << r.transform->scale() << "\n";
    os << "rotation: [" << q.x() << ", " << q.y() << ", " << q.z() << ", " << q.w() << "]\n";
    os << "translation: [" << t.x() << ", " << t.y() << ", " << t.z() << "]\n";
  }
  if (r.covariance) writeMatrix(os, "covariance", *r.covariance);
  if (r.information) writeMatrix(os, "information", *r.information);
  if (r.scale_stddev) os << "scale_stddev: " << *r.scale_stddev << "\n";
  if (r.fitness_rmse) os << "fitness_rmse: " << *r.fitness_rmse << "\n";
  if (r.correspondences) os << "correspondences: " << *r.correspondences << "\n";
  if (r.scale_difference_detected) {
    os << "scale_difference_detected: " << (*r.scale_difference_detected ? "true" : "false") << "\n";
  }
  if (r.detected_scale_ratio) os << "detected_scale_ratio: " << *r.detected_scale_ratio << "\n";
  if (r.condition_number) os << "condition_number: " << *r.condition_number << "\n";
  if (r.noise_stddev) os << "noise_stddev: " << *r.noise_stddev << "\n";
  if (r.icp_iterations > 0) os << "icp_iterations: " << r.icp_iterations << "\n";
  if (r.reversed && *r.reversed) os << "reversed: true\n";
  if (r.overlap) os << "overlap: " << *r.overlap << "\n";
  if (r.keyframe_transform) {
    const Eigen::Quaterniond q = r.keyframe_transform->quaternion();
    const Eigen::Vector3d& t = r.keyframe_transform->translation();
    os << "keyframe_estimate:\n";
    os << "  scale: " << r.keyframe_transform->scale() << "\n";
    os << "  rotation: [" << q.x() << ", " << q.y() << ", " << q.z() << ", " << q.w() << "]\n";
    os << "  translation: [" << t.x() << ", " << t.y() << ", " << t.z() << "]\n";
    if (r.keyframe_scale_stddev) os << "  scale_stddev: " << *r.keyframe_scale_stddev << "\n";
    if (r.keyframe_covariance) writeMatrix(os, "  covariance", *r.keyframe_covariance);
  }
  if (r.refinement_kept) {
    os << "refinement: {kept: " << (*r.refinement_kept ? "true" : "false");
    if (r.refinement_combined && *r.refinement_combined) os << ", combined: true";
    if (r.refinement_chi2) os << ", chi2: " << *r.refinement_chi2;
    if (r.refinement_reversed && *r.refinement_reversed) os << ", reversed: true";
    os << "}\n";
  }
  if (r.keyframe_edge) {
    const KeyframeEdge& e = *r.keyframe_edge;
    const Eigen::Quaterniond q = e.transform.quaternion();
    const Eigen::Vector3d& t = e.transform.translation();
    os << "keyframe_edge:\n";
    os << "  source_keyframe: " << e.source_keyframe << "\n";
    os << "  target_keyframe: " << e.target_keyframe << "\n";
    os << "  scale: " << e.transform.scale() << "\n";
    os << "  rotation: [" << q.x() << ", " << q.y() << ", " << q.z() << ", " << q.w() << "]\n";
    os << "  translation: [" << t.x() << ", " << t.y() << ", " << t.z() << "]\n";
    writeMatrix(os, "  covariance", e.covariance);
  }
  if (!r.keyframe_pairs.empty()) {
    os << "keyframe_pairs:\n";
    for (const KeyframePairReport& p : r.keyframe_pairs) {
      os << "  - {source: " << p.source_keyframe << ", target: " << p.target_keyframe << ", inliers: " << p.inliers
         << ", depth_matches: " << p.depth_matches << ", used: " << (p.used ? "true" : "false")
         << ", note: " << quoted(p.note) << "}\n";
    }
  }
  os << std::setprecision(4);
  const StageTimings& t = r.timings;
  os << "timings_ms: {features: " << t.features << ", relative_pose: " << t.relative_pose << ", scale: " << t.scale
     << ", filters: " << t.filters << ", icp: " << t.icp << ", covariance: " << t.covariance
     << ", arbitration: " << t.arbitration << ", total: " << t.total << "}\n";
  return os.str();
}

}  // namespace pcr_pro
