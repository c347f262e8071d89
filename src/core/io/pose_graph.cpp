#include "pcr_pro/io/pose_graph.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

#include "pcr_pro/geometry/similarity_fit.h"
#include "pcr_pro/io/text_escape.h"

namespace pcr_pro {
namespace {

// f_k(σ) = ∫₀¹ τᵏ e^(στ) dτ. Near σ = 0 its power series (terms σⁿ / (n! (n + k + 1)), exact to
// rounding within 30 terms for |σ| < 1); elsewhere the recurrence f_k = (e^σ - k f_(k-1)) / σ,
// which multiplies an error by k / |σ| < 5 per step there.
double expMoment(int k, double sigma) {
  if (std::abs(sigma) < 1.0) {
    double sum = 0.0, power = 1.0;  // σⁿ / n!
    for (int n = 0; n < 30; ++n) {
      sum += power / static_cast<double>(n + k + 1);
      power *= sigma / static_cast<double>(n + 1);
    }
    return sum;
  }
  double f = std::expm1(sigma) / sigma;
  for (int j = 1; j <= k; ++j) f = (std::exp(sigma) - j * f) / sigma;
  return f;
}

// W(ω, σ) = ∫₀¹ e^(στ) exp(τ[ω]×) dτ = a [ω]× + b [ω]×² + c I: the map from the algebra's υ to the
// group's translation. With θ = |ω|: c = f_0(σ), a = ∫ e^(στ) sin(θτ)/θ, b = ∫ e^(στ) (1 - cos θτ)/θ².
// Below θ = 1e-3 the sine and cosine take their Taylor series to θ² (the next term is θ⁴ < 1e-12).
Eigen::Matrix3d algebraToTranslation(const Eigen::Vector3d& omega, double sigma) {
  const double theta = omega.norm();
  const double c = expMoment(0, sigma);
  double a = 0.0, b = 0.0;
  if (theta < 1e-3) {
    a = expMoment(1, sigma) - theta * theta * expMoment(3, sigma) / 6.0;
    b = expMoment(2, sigma) / 2.0 - theta * theta * expMoment(4, sigma) / 24.0;
  } else {
    const double s = std::exp(sigma), d = sigma * sigma + theta * theta;
    const double sin_t = std::sin(theta), cos_t = std::cos(theta);
    a = (s * (sigma * sin_t - theta * cos_t) + theta) / (theta * d);
    b = (c - (s * (sigma * cos_t + theta * sin_t) - sigma) / d) / (theta * theta);
  }
  const Eigen::Matrix3d w = skew(omega);
  return a * w + b * w * w + c * Eigen::Matrix3d::Identity();
}

// pcr_pro's tangent order (x y z, rx ry rz, σ) -> g2o's (ω, υ, σ): g2o index i holds ours kFromOurs[i].
constexpr int kFromOurs[7] = {3, 4, 5, 0, 1, 2, 6};

std::string cleanName(std::string name) {
  for (char& c : name) {
    if (static_cast<unsigned char>(c) <= 0x20 || c == 0x7f) c = '_';
  }
  return name.empty() ? std::string("agent") : name;
}

std::string number(double v, int digits = 17) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*g", digits, v);
  return buf;
}

const MapKeyframe* findKeyframe(const AgentMap& map, long id) {
  for (const MapKeyframe& kf : map.keyframes) {
    if (kf.id == id) return &kf;
  }
  return nullptr;
}

void addVertices(const AgentMap& map, const std::string& name, const Sim3& to_world, PoseGraph* graph) {
  std::vector<const MapKeyframe*> sorted;
  for (const MapKeyframe& kf : map.keyframes) sorted.push_back(&kf);
  std::sort(sorted.begin(), sorted.end(), [](const MapKeyframe* a, const MapKeyframe* b) { return a->id < b->id; });
  for (const MapKeyframe* kf : sorted) {
    PoseGraphVertex v;
    v.id = static_cast<int>(graph->vertices.size());
    v.agent = name;
    v.keyframe = kf->id;
    v.camera_to_world = to_world * kf->pose;
    v.fx = map.camera.fx;
    v.fy = map.camera.fy;
    v.cx = map.camera.cx;
    v.cy = map.camera.cy;
    graph->vertices.push_back(v);
  }
}

int vertexOf(const PoseGraph& graph, const std::string& agent, long keyframe) {
  for (const PoseGraphVertex& v : graph.vertices) {
    if (v.agent == agent && v.keyframe == keyframe) return v.id;
  }
  return -1;
}

// Reads the numbers of one g2o line.
class LineReader {
 public:
  LineReader(std::istringstream* in, const std::string& where) : in_(in), where_(where) {}
  double number(const char* what) {
    std::string token;
    if (!(*in_ >> token)) throw InputError(where_ + ": missing " + what);
    char* end = nullptr;
    const double v = std::strtod(token.c_str(), &end);
    if (end != token.c_str() + token.size() || !std::isfinite(v)) {
      throw InputError(where_ + ": " + what + ": not a finite number: '" + printable(token, 40) + "'");
    }
    return v;
  }
  int integer(const char* what) {
    const double v = number(what);
    if (v != std::floor(v) || std::abs(v) > 2147483647.0) {
      throw InputError(where_ + ": " + what + ": not an integer id: " + pcr_pro::number(v));
    }
    return static_cast<int>(v);
  }
  void end() {
    std::string extra;
    if (*in_ >> extra) throw InputError(where_ + ": unexpected extra value '" + printable(extra, 40) + "'");
  }

 private:
  std::istringstream* in_;
  std::string where_;
};

G2oTangent readTangent(LineReader* r) {
  G2oTangent v;
  for (int i = 0; i < 7; ++i) v(i) = r->number("Sim(3) tangent");
  return v;
}

}  // namespace

Sim3 g2oSim3Exp(const G2oTangent& tangent) {
  const Eigen::Vector3d omega = tangent.head<3>();
  const double sigma = tangent(6);
  return Sim3(std::exp(sigma), expSO3(omega), algebraToTranslation(omega, sigma) * tangent.segment<3>(3));
}

G2oTangent g2oSim3Log(const Sim3& s) {
  const Eigen::AngleAxisd aa(s.rotation());
  const Eigen::Vector3d omega = aa.angle() * aa.axis();
  const double sigma = std::log(s.scale());
  G2oTangent out;
  out << omega, algebraToTranslation(omega, sigma).partialPivLu().solve(s.translation()), sigma;
  return out;
}

Matrix7d g2oEdgeCovariance(const MergeEdge& edge, const Sim3& source_pose) {
  // C = A ∘ exp(-δ) ∘ P_t with A = (S_ts ∘ P_s)⁻¹ when S_ts = exp(δ) ∘ Ŝ_ts; A exp(-δ) = exp(-Ad(A) δ) A,
  // so C's left perturbation is -Ad(A) δ (similarityAdjoint()), whose sign the covariance drops.
  const Matrix7d ad = similarityAdjoint((edge.target_from_source * source_pose).inverse());
  const Matrix7d ours = ad * edge.covariance * ad.transpose();
  Matrix7d g2o;
  for (int i = 0; i < 7; ++i) {
    for (int j = 0; j < 7; ++j) g2o(i, j) = ours(kFromOurs[i], kFromOurs[j]);
  }
  return 0.5 * (g2o + g2o.transpose());
}

PoseGraph mergePoseGraph(const AgentMap& target, const std::string& target_name, const AgentMap& source,
                         const std::string& source_name, const MergeEdge& edge) {
  const std::string tname = cleanName(target_name), sname = cleanName(source_name);
  if (tname == sname) throw InputError("pose graph: the two agents have the same name '" + tname + "'");
  if (target.keyframes.empty() || source.keyframes.empty()) throw InputError("pose graph: a map has no keyframe");
  const MapKeyframe* source_anchor = findKeyframe(source, edge.source_keyframe);
  if (!findKeyframe(target, edge.target_keyframe) || !source_anchor) {
    throw InputError("pose graph: the edge's keyframes (source " + std::to_string(edge.source_keyframe) + ", target " +
                     std::to_string(edge.target_keyframe) + ") are not both in their maps");
  }
  const Matrix7d cov = g2oEdgeCovariance(edge, source_anchor->pose);
  const Eigen::SelfAdjointEigenSolver<Matrix7d> eig(cov);
  if (!cov.allFinite() || !(eig.eigenvalues()(0) > 1e-14 * eig.eigenvalues()(6))) {
    throw InputError("pose graph: the edge's covariance is not finite and positive definite (export successful merges only)");
  }
  PoseGraph graph;
  addVertices(target, tname, Sim3(), &graph);
  addVertices(source, sname, edge.target_from_source, &graph);
  PoseGraphEdge e;
  e.from = vertexOf(graph, tname, edge.target_keyframe);
  e.to = vertexOf(graph, sname, edge.source_keyframe);
  // S = camera_to_world⁻¹ for every vertex: C = S_j ∘ S_i⁻¹.
  e.measurement = graph.vertices[static_cast<std::size_t>(e.to)].camera_to_world.inverse() *
                  graph.vertices[static_cast<std::size_t>(e.from)].camera_to_world;
  const Matrix7d info = eig.eigenvectors() * eig.eigenvalues().cwiseInverse().asDiagonal() * eig.eigenvectors().transpose();
  e.information = 0.5 * (info + info.transpose());
  graph.edges.push_back(e);
  graph.fixed.push_back(0);
  return graph;
}

std::string toG2o(const PoseGraph& graph) {
  std::ostringstream out;
  out << "# pcr_pro pose graph (g2o): vertices = keyframes (camera -> target map), edges = map merges\n";
  for (const PoseGraphVertex& v : graph.vertices) {
    out << "# pcr_pro vertex " << v.id << " agent " << cleanName(v.agent) << " keyframe " << v.keyframe << "\n";
  }
  for (const PoseGraphVertex& v : graph.vertices) {
    out << "VERTEX_SIM3:EXPMAP " << v.id;
    const G2oTangent t = g2oSim3Log(v.camera_to_world);
    for (int i = 0; i < 7; ++i) out << " " << number(t(i));
    for (double k : {v.fx, v.fy, v.cx, v.cy}) out << " " << number(k);
    out << "\n";
  }
  for (const PoseGraphEdge& e : graph.edges) {
    out << "EDGE_SIM3:EXPMAP " << e.from << " " << e.to;
    const G2oTangent t = g2oSim3Log(e.measurement.inverse());
    for (int i = 0; i < 7; ++i) out << " " << number(t(i));
    for (int i = 0; i < 7; ++i) {
      for (int j = i; j < 7; ++j) out << " " << number(e.information(i, j));
    }
    out << "\n";
  }
  for (int id : graph.fixed) out << "FIX " << id << "\n";
  return out.str();
}

PoseGraph parseG2o(const std::string& text, const std::string& origin) {
  PoseGraph graph;
  std::map<int, std::size_t> index;  // vertex id -> position
  std::map<int, std::pair<std::string, long>> names;
  std::istringstream lines(text);
  std::string line;
  for (int n = 1; std::getline(lines, line); ++n) {
    const std::string where = origin + ": line " + std::to_string(n);
    std::istringstream in(line);
    std::string tag;
    if (!(in >> tag)) continue;
    LineReader r(&in, where);
    if (tag[0] == '#') {
      // "# pcr_pro vertex <id> agent <name> keyframe <id>" (toG2o()); any other comment is skipped.
      std::string mark, vertex, agent_word, agent, kf_word;
      int id = 0;
      long kf = 0;
      if (tag == "#" && in >> mark >> vertex >> id >> agent_word >> agent >> kf_word >> kf && mark == "pcr_pro" &&
          vertex == "vertex" && agent_word == "agent" && kf_word == "keyframe") {
        names[id] = {agent, kf};
      }
      continue;
    }
    if (tag == "VERTEX_SIM3:EXPMAP") {
      PoseGraphVertex v;
      v.id = r.integer("vertex id");
      if (index.count(v.id)) throw InputError(where + ": vertex " + std::to_string(v.id) + " defined twice");
      v.camera_to_world = g2oSim3Exp(readTangent(&r));
      v.fx = r.number("fx");
      v.fy = r.number("fy");
      v.cx = r.number("cx");
      v.cy = r.number("cy");
      r.end();
      index[v.id] = graph.vertices.size();
      graph.vertices.push_back(v);
    } else if (tag == "EDGE_SIM3:EXPMAP") {
      PoseGraphEdge e;
      e.from = r.integer("first vertex id");
      e.to = r.integer("second vertex id");
      if (!index.count(e.from) || !index.count(e.to)) throw InputError(where + ": edge names an undefined vertex");
      e.measurement = g2oSim3Exp(readTangent(&r)).inverse();
      for (int i = 0; i < 7; ++i) {
        for (int j = i; j < 7; ++j) e.information(i, j) = e.information(j, i) = r.number("information");
      }
      r.end();
      graph.edges.push_back(e);
    } else if (tag == "FIX") {
      const int id = r.integer("vertex id");
      if (!index.count(id)) throw InputError(where + ": FIX names an undefined vertex " + std::to_string(id));
      r.end();
      graph.fixed.push_back(id);
    } else {
      throw InputError(where + ": unknown tag '" + printable(tag, 40) + "' (expected VERTEX_SIM3:EXPMAP, "
                       "EDGE_SIM3:EXPMAP or FIX)");
    }
  }
  for (PoseGraphVertex& v : graph.vertices) {
    const auto it = names.find(v.id);
    if (it != names.end()) std::tie(v.agent, v.keyframe) = it->second;
  }
  return graph;
}

std::string toTum(const PoseGraph& graph) {
  std::ostringstream out;
  out << "# pcr_pro fused keyframes (TUM): timestamp(= keyframe id) tx ty tz qx qy qz qw, camera in the "
         "target map\n";
  std::string agent;
  for (const PoseGraphVertex& v : graph.vertices) {
    if (v.id == 0 || v.agent != agent) {
      agent = v.agent;
      out << "# agent " << cleanName(agent) << "\n";
    }
    const Eigen::Quaterniond q(v.camera_to_world.rotation());
    const Eigen::Vector3d& t = v.camera_to_world.translation();
    out << v.keyframe;
    for (double x : {t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w()}) out << " " << number(x, 10);
    out << "\n";
  }
  return out.str();
}

void writeTextFileAtomically(const std::string& path, const std::string& text) {
  const std::string part = path + ".part";
  {
    std::ofstream out(part, std::ios::binary | std::ios::trunc);
    out << text;
    out.flush();
    if (!out) throw InputError(path + ": cannot write file");
  }
  std::error_code ec;
  std::filesystem::rename(part, path, ec);
  if (ec) {
    const std::string why = ec.message();
    std::filesystem::remove(part, ec);
    throw InputError(path + ": cannot write file (" + why + ")");
  }
}

}  // namespace pcr_pro
