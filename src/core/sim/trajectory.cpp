#include "sim/trajectory.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "sim/sim_random.h"

namespace pcr_pro {
namespace sim_detail {
namespace {

constexpr double kDeg = M_PI / 180.0;
// Fine steps along a path between which keyframes are chosen.
constexpr int kPathSteps = 2000;
// Motion measure: metres per radian of rotation.
constexpr double kMetresPerRadian = 0.5;

// A smooth random wobble over the path parameter s in [0, 1]: two sinusoids of random phase,
// 0.5-1.5 and 1.5-3 cycles over the path, peak value at most `amplitude`.
struct Wobble {
  double amplitude = 0.0, f1 = 1.0, p1 = 0.0, f2 = 2.0, p2 = 0.0;
  Wobble() = default;
  Wobble(double a, std::mt19937_64& rng)
      : amplitude(a), f1(uniform(rng, 0.5, 1.5)), p1(uniform(rng, 0.0, 2 * M_PI)), f2(uniform(rng, 1.5, 3.0)),
        p2(uniform(rng, 0.0, 2 * M_PI)) {}
  double at(double s) const {
    return amplitude * (0.6 * std::sin(2 * M_PI * f1 * s + p1) + 0.4 * std::sin(2 * M_PI * f2 * s + p2));
  }
};

struct Wobbles {
  Wobble height, yaw, pitch, roll;
};

// Optical-frame rotation (x right, y down, z forward) looking along `forward`, world z up.
Eigen::Matrix3d lookAlong(const Eigen::Vector3d& forward) {
  const Eigen::Vector3d f = forward.normalized();
  Eigen::Vector3d right = f.cross(Eigen::Vector3d::UnitZ());
  if (right.norm() < 1e-9) right = Eigen::Vector3d::UnitX();  // looking straight up or down
  right.normalize();
  Eigen::Matrix3d r;
  r.col(0) = right;
  r.col(1) = f.cross(right);
  r.col(2) = f;
  return r;
}

std::string num(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

// The camera pose at path parameter s in [0, 1].
Sim3 cameraAt(const World& world, const TrajectoryOptions& o, const AgentPath& path, const Wobbles& w, double s,
              const std::string& field) {
  const double phi = (path.azimuth_start_deg + s * path.azimuth_span_deg) * kDeg;
  const Eigen::Vector3d u(std::cos(phi), std::sin(phi), 0.0);
  const Eigen::Vector3d centre = 0.5 * (world.room_min + world.room_max);
  const Eigen::Vector3d half = 0.5 * (world.room_max - world.room_min);
  // The wall point on the horizontal ray from the centre.
  const double rx = std::abs(u.x()) > 1e-12 ? half.x() / std::abs(u.x()) : 1e300;
  const double ry = std::abs(u.y()) > 1e-12 ? half.y() / std::abs(u.y()) : 1e300;
  Eigen::Vector3d target = centre + std::min(rx, ry) * u;
  target.z() = world.room_min.z() + o.target_height;
  const double a = path.view_angle_deg * kDeg;
  const Eigen::Vector3d back(-std::cos(a) * u.x() + std::sin(a) * u.y(), -std::sin(a) * u.x() - std::cos(a) * u.y(), 0.0);
  Eigen::Vector3d nominal = target + o.distance * back;
  nominal.z() = world.room_min.z() + o.camera_height + w.height.at(s);
  // Keep the camera free: closer to the looked-at point, else towards the room centre.
  Eigen::Vector3d camera = nominal;
  for (double d = o.distance; !world.isFree(camera, o.clearance) && d > 0.3; d -= 0.05) {
    camera = target + d * back;
    camera.z() = nominal.z();
  }
  Eigen::Vector3d middle = centre;
  middle.z() = nominal.z();
  for (double t = 0.05; !world.isFree(camera, o.clearance) && t <= 1.0 + 1e-9; t += 0.05) {
    camera = (1.0 - t) * nominal + t * middle;
  }
  if (!world.isFree(camera, o.clearance)) {
    throw InputError(field + ": the camera path cannot keep trajectory.clearance " + num(o.clearance) +
                     " m from walls and boxes at azimuth " + num(phi / kDeg) + " deg");
  }
  Eigen::Vector3d forward = target - camera;
  forward = Eigen::AngleAxisd(w.yaw.at(s) * kDeg, Eigen::Vector3d::UnitZ()) * forward;
  Eigen::Matrix3d r = lookAlong(forward);
  r = r * Eigen::AngleAxisd(w.pitch.at(s) * kDeg, Eigen::Vector3d::UnitX()) *
      Eigen::AngleAxisd(w.roll.at(s) * kDeg, Eigen::Vector3d::UnitZ());
  return Sim3(1.0, r, camera);
}

double motionBetween(const Sim3& a, const Sim3& b) {
  return (a.translation() - b.translation()).norm() + kMetresPerRadian * rotationDistance(a.rotation(), b.rotation());
}

}  // namespace

PathKeyframes keyframePath(const World& world, const TrajectoryOptions& o, const AgentPath& path,
                           const std::string& field) {
  std::mt19937_64 rng(path.seed);
  Wobbles w;
  w.height = Wobble(o.height_wobble, rng);
  w.yaw = Wobble(o.yaw_wobble_deg, rng);
  w.pitch = Wobble(o.pitch_wobble_deg, rng);
  w.roll = Wobble(o.roll_wobble_deg, rng);
  PathKeyframes out;
  Sim3 previous = cameraAt(world, o, path, w, 0.0, field);
  out.poses.push_back(previous);
  out.motion.push_back(0.0);
  double motion = 0.0;
  for (int k = 1; k <= kPathSteps && static_cast<int>(out.poses.size()) < o.max_keyframes; ++k) {
    const Sim3 pose = cameraAt(world, o, path, w, static_cast<double>(k) / kPathSteps, field);
    motion += motionBetween(previous, pose);
    previous = pose;
    const Sim3& last = out.poses.back();
    if ((pose.translation() - last.translation()).norm() >= o.keyframe_distance ||
        rotationDistance(pose.rotation(), last.rotation()) >= o.keyframe_angle_deg * kDeg) {
      out.poses.push_back(pose);
      out.motion.push_back(motion);
    }
  }
  return out;
}

DriftedPoses driftPoses(const PathKeyframes& path, const Sim3& world_to_map, double scale_drift, double bend_deg,
                        const DriftOptions& o, std::uint64_t seed) {
  DriftedPoses out;
  const std::size_t n = path.poses.size();
  const double total = path.motion.empty() ? 0.0 : path.motion.back();
  std::mt19937_64 rng(seed);
  Sim3 drifted = world_to_map * path.poses[0];
  for (std::size_t k = 0; k < n; ++k) {
    if (k > 0) {
      // Odometry: the true relative motion, then this step's share of the drift in the new
      // camera's frame (scale, and a rotation about the world vertical).
      const double share = total > 0.0 ? (path.motion[k] - path.motion[k - 1]) / total : 0.0;
      const Eigen::Vector3d up = path.poses[k].rotation().transpose() * Eigen::Vector3d::UnitZ();
      const Sim3 step_error(std::pow(1.0 + scale_drift, share),
                            Eigen::Matrix3d(Eigen::AngleAxisd(share * bend_deg * kDeg, up)), Eigen::Vector3d::Zero());
      drifted = drifted * (path.poses[k - 1].inverse() * path.poses[k]) * step_error;
    }
    // Jitter of this keyframe's estimate (the first keyframe defines the map frame: none).
    const double gr = gaussian(rng), gt = gaussian(rng), gs = gaussian(rng);
    const Eigen::Vector3d axis(gaussian(rng), gaussian(rng), gaussian(rng));
    const Eigen::Vector3d dir(gaussian(rng), gaussian(rng), gaussian(rng));
    Sim3 tracked = drifted;
    if (k > 0) {
      const Sim3 noise(std::exp(o.pose_noise_scale * gs),
                       Eigen::Matrix3d(Eigen::AngleAxisd(o.pose_noise_rotation_deg * kDeg * gr, axis.normalized())),
                       o.pose_noise_translation * gt * dir.normalized());
      tracked = drifted * noise;
    }
    out.tracked.push_back(tracked);
    out.map.push_back(interpolate(tracked, world_to_map * path.poses[k], o.loop_closure));
  }
  return out;
}

Sim3 interpolate(const Sim3& a, const Sim3& b, double f) {
  if (f <= 0.0) return a;
  if (f >= 1.0) return b;
  const double scale = std::exp((1.0 - f) * std::log(a.scale()) + f * std::log(b.scale()));
  const Eigen::Quaterniond q = a.quaternion().slerp(f, b.quaternion());
  return Sim3(scale, q, (1.0 - f) * a.translation() + f * b.translation());
}

}  // namespace sim_detail
}  // namespace pcr_pro
