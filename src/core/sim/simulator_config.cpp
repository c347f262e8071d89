// SimulatorOptions: validation, YAML parsing (config/simulator.yaml) and YAML output.
#include <yaml-cpp/yaml.h>

#include <cctype>
#include <cmath>
#include <cstdlib>
#include <set>
#include <sstream>

#include "io/yaml_block.h"
#include "pcr_pro/sim/simulator.h"

namespace pcr_pro {
namespace {

using config_detail::Block;

// Shortest decimal text that reads back to the same double.
std::string num(double v) {
  for (int precision : {6, 12, 15, 17}) {
    std::ostringstream s;
    s.precision(precision);
    s << v;
    if (std::strtod(s.str().c_str(), nullptr) == v) return s.str();
  }
  return "nan";
}

void range(const std::string& key, double v, double lo, double hi) {
  if (!(v >= lo && v <= hi)) throw InputError(key + ": must be in [" + num(lo) + ", " + num(hi) + "], got " + num(v));
}

void validateTrajectory(const TrajectoryOptions& t, const WorldOptions& w) {
  range("trajectory.azimuth_span_deg", t.azimuth_span_deg, 1.0, 360.0);
  range("trajectory.distance", t.distance, 0.5, 20.0);
  range("trajectory.clearance", t.clearance, 0.0, 2.0);
  range("trajectory.height_wobble", t.height_wobble, 0.0, 2.0);
  range("trajectory.camera_height", t.camera_height, t.clearance + t.height_wobble,
        w.room_height - t.clearance - t.height_wobble);
  range("trajectory.target_height", t.target_height, 0.0, w.room_height);
  range("trajectory.yaw_wobble_deg", t.yaw_wobble_deg, 0.0, 45.0);
  range("trajectory.pitch_wobble_deg", t.pitch_wobble_deg, 0.0, 45.0);
  range("trajectory.roll_wobble_deg", t.roll_wobble_deg, 0.0, 45.0);
  range("trajectory.keyframe_distance", t.keyframe_distance, 1e-3, 100.0);
  range("trajectory.keyframe_angle_deg", t.keyframe_angle_deg, 0.1, 180.0);
  range("trajectory.max_keyframes", t.max_keyframes, 2, 1000);
}

void validateDrift(const std::string& prefix, double scale_drift, double bend_deg) {
  range(prefix + "scale_drift", scale_drift, -0.5, 0.5);
  range(prefix + "bend_deg", bend_deg, -45.0, 45.0);
}

void validateAgent(const AgentOptions& a, std::size_t i) {
  const std::string f = "per_agent[" + std::to_string(i) + "].";
  if (!a.name.empty()) {
    for (char c : a.name) {
      if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_')) {
        throw InputError(f + "name: only letters, digits and '_' (it names a directory and ROS topics), got '" + a.name + "'");
      }
    }
  }
  if (a.scale) range(f + "scale", *a.scale, 1e-3, 1e3);
  if (a.azimuth_start_deg) range(f + "azimuth_start_deg", *a.azimuth_start_deg, -720.0, 720.0);
  if (a.azimuth_span_deg) range(f + "azimuth_span_deg", *a.azimuth_span_deg, 1.0, 360.0);
  if (a.view_angle_deg) range(f + "view_angle_deg", *a.view_angle_deg, -60.0, 60.0);
  validateDrift(f, a.scale_drift.value_or(0.0), a.bend_deg.value_or(0.0));
}

// Duplicate keys are errors (yaml-cpp keeps one of them silently).
void checkDuplicates(const YAML::Node& node, const std::string& path, const std::string& origin) {
  if (node.IsMap()) {
    std::set<std::string> seen;
    for (const auto& kv : node) {
      const std::string key = kv.first.as<std::string>();
      const std::string child = path.empty() ? key : path + "." + key;
      if (!seen.insert(key).second) throw InputError(origin + ": " + child + ": duplicate key");
      checkDuplicates(kv.second, child, origin);
    }
  } else if (node.IsSequence()) {
    for (std::size_t i = 0; i < node.size(); ++i) checkDuplicates(node[i], path + "[" + std::to_string(i) + "]", origin);
  }
}

void optionalDouble(Block* b, const std::string& key, std::optional<double>* v) {
  if (!b->child(key)) return;  // child() marks the key as known
  double x = 0.0;
  b->get(key, &x);
  *v = x;
}

void loadWorld(const YAML::Node& node, const std::string& origin, WorldOptions* w) {
  Block b(node, "world", origin);
  b.get("room_length", &w->room_length);
  b.get("room_width", &w->room_width);
  b.get("room_height", &w->room_height);
  b.get("boxes", &w->boxes);
  b.get("max_box_depth", &w->max_box_depth);
  b.get("max_wall_box_height", &w->max_wall_box_height);
  b.get("max_free_box_height", &w->max_free_box_height);
  b.get("free_box_wall_distance", &w->free_box_wall_distance);
  b.get("ambient", &w->ambient);
  Block t(b.child("texture"), "world.texture", origin);
  t.get("texel", &w->texture.texel);
  t.get("min_shape_size", &w->texture.min_shape_size);
  t.get("max_shape_size", &w->texture.max_shape_size);
  t.get("coverage", &w->texture.coverage);
  t.get("detail_decay", &w->texture.detail_decay);
  t.get("blur", &w->texture.blur);
  t.finish();
  b.finish();
}

void loadTrajectory(const YAML::Node& node, const std::string& origin, TrajectoryOptions* t) {
  Block b(node, "trajectory", origin);
  b.get("azimuth_span_deg", &t->azimuth_span_deg);
  b.get("distance", &t->distance);
  b.get("camera_height", &t->camera_height);
  b.get("target_height", &t->target_height);
  b.get("height_wobble", &t->height_wobble);
  b.get("yaw_wobble_deg", &t->yaw_wobble_deg);
  b.get("pitch_wobble_deg", &t->pitch_wobble_deg);
  b.get("roll_wobble_deg", &t->roll_wobble_deg);
  b.get("keyframe_distance", &t->keyframe_distance);
  b.get("keyframe_angle_deg", &t->keyframe_angle_deg);
  b.get("max_keyframes", &t->max_keyframes);
  b.get("clearance", &t->clearance);
  b.finish();
}

void loadMapBlocks(Block* top, const std::string& origin, SimulatorOptions* o) {
  Block r(top->child("render"), "render", origin);
  r.get("supersampling", &o->render.supersampling);
  r.get("image_noise", &o->render.image_noise);
  r.get("near", &o->render.near);
  r.finish();
  Block l(top->child("layout"), "layout", origin);
  l.get("overlap", &o->layout.overlap);
  l.get("view_angle_difference_deg", &o->layout.view_angle_difference_deg);
  l.get("first_azimuth_deg", &o->layout.first_azimuth_deg);
  l.finish();
  Block d(top->child("drift"), "drift", origin);
  d.get("scale_drift", &o->drift.scale_drift);
  d.get("bend_deg", &o->drift.bend_deg);
  d.get("pose_noise_rotation_deg", &o->drift.pose_noise_rotation_deg);
  d.get("pose_noise_translation", &o->drift.pose_noise_translation);
  d.get("pose_noise_scale", &o->drift.pose_noise_scale);
  d.get("loop_closure", &o->drift.loop_closure);
  d.finish();
  Block m(top->child("map"), "map", origin);
  m.get("cloud_fraction", &o->map.cloud_fraction);
  m.get("depth_images", &o->map.depth_images);
  Block s(m.child("semi_dense"), "map.semi_dense", origin);
  s.get("min_gradient", &o->map.semi_dense.min_gradient);
  s.get("idepth_noise", &o->map.semi_dense.idepth_noise);
  s.get("reference_gradient", &o->map.semi_dense.reference_gradient);
  s.get("outlier_fraction", &o->map.semi_dense.outlier_fraction);
  s.get("subsample", &o->map.semi_dense.subsample);
  s.get("noise_correlation", &o->map.semi_dense.noise_correlation);
  s.finish();
  m.finish();
}

void loadAgents(const YAML::Node& node, const std::string& origin, std::vector<AgentOptions>* agents) {
  if (!node || node.IsNull()) return;
  if (!node.IsSequence()) throw InputError(origin + ": per_agent: must be a list");
  for (std::size_t i = 0; i < node.size(); ++i) {
    Block b(node[i], "per_agent[" + std::to_string(i) + "]", origin);
    AgentOptions a;
    b.get("name", &a.name);
    optionalDouble(&b, "scale", &a.scale);
    optionalDouble(&b, "azimuth_start_deg", &a.azimuth_start_deg);
    optionalDouble(&b, "azimuth_span_deg", &a.azimuth_span_deg);
    optionalDouble(&b, "view_angle_deg", &a.view_angle_deg);
    optionalDouble(&b, "scale_drift", &a.scale_drift);
    optionalDouble(&b, "bend_deg", &a.bend_deg);
    b.finish();
    agents->push_back(a);
  }
}

void optionalYaml(std::ostringstream& y, const char* key, const std::optional<double>& v) {
  if (v) y << ", " << key << ": " << num(*v);
}

}  // namespace

void validate(const SimulatorOptions& o) {
  range("agents", o.agents, 1, 26);
  if (o.per_agent.size() > static_cast<std::size_t>(o.agents)) {
    throw InputError("per_agent: " + std::to_string(o.per_agent.size()) + " entries for " + std::to_string(o.agents) +
                     " agents");
  }
  std::set<std::string> names;
  for (int i = 0; i < o.agents; ++i) {
    const auto iu = static_cast<std::size_t>(i);
    std::string name = std::string("agent_") + static_cast<char>('a' + i);
    if (iu < o.per_agent.size()) {
      validateAgent(o.per_agent[iu], iu);
      if (!o.per_agent[iu].name.empty()) name = o.per_agent[iu].name;
    }
    if (!names.insert(name).second) throw InputError("per_agent[" + std::to_string(i) + "].name: duplicate agent name " + name);
  }
  const PinholeCamera& c = o.camera;
  if (!c.valid() || c.width > 4096 || c.height > 4096 || c.width < 16 || c.height < 16) {
    throw InputError("camera: fx, fy must be finite and > 0, width and height in [16, 4096]");
  }
  validate(o.world);
  validate(o.render);
  validateTrajectory(o.trajectory, o.world);
  range("layout.overlap", o.layout.overlap, 0.0, 1.0);
  range("layout.view_angle_difference_deg", o.layout.view_angle_difference_deg, 0.0, 120.0);
  range("layout.first_azimuth_deg", o.layout.first_azimuth_deg, -720.0, 720.0);
  validateDrift("drift.", o.drift.scale_drift, o.drift.bend_deg);
  range("drift.pose_noise_rotation_deg", o.drift.pose_noise_rotation_deg, 0.0, 30.0);
  range("drift.pose_noise_translation", o.drift.pose_noise_translation, 0.0, 10.0);
  range("drift.pose_noise_scale", o.drift.pose_noise_scale, 0.0, 0.5);
  range("drift.loop_closure", o.drift.loop_closure, 0.0, 1.0);
  try {
    validate(o.map.semi_dense);
  } catch (const InputError& e) {
    throw InputError(std::string("map.") + e.what());
  }
  range("map.cloud_fraction", o.map.cloud_fraction, 1e-6, 1.0);
  if (o.map.depth_images != "dense" && o.map.depth_images != "semi_dense" && o.map.depth_images != "none") {
    throw InputError("map.depth_images: must be dense, semi_dense or none, got '" + o.map.depth_images + "'");
  }
  range("min_overlap", o.min_overlap, 0.0, 1.0);
}

SimulatorOptions parseSimulatorConfig(const std::string& text, const std::string& origin) {
  const YAML::Node root = config_detail::parseYaml(text, origin);
  SimulatorOptions o;
  if (!root || root.IsNull()) return o;
  checkDuplicates(root, "", origin);
  Block top(root, "", origin);
  top.get("seed", &o.seed);
  top.get("agents", &o.agents);
  top.get("min_overlap", &o.min_overlap);
  Block cam(top.child("camera"), "camera", origin);
  cam.get("fx", &o.camera.fx);
  cam.get("fy", &o.camera.fy);
  cam.get("cx", &o.camera.cx);
  cam.get("cy", &o.camera.cy);
  cam.get("width", &o.camera.width);
  cam.get("height", &o.camera.height);
  cam.finish();
  loadWorld(top.child("world"), origin, &o.world);
  loadTrajectory(top.child("trajectory"), origin, &o.trajectory);
  loadMapBlocks(&top, origin, &o);
  loadAgents(top.child("per_agent"), origin, &o.per_agent);
  top.finish();
  config_detail::validateIn(o, origin);
  return o;
}

SimulatorOptions loadSimulatorConfig(const std::string& path) {
  return parseSimulatorConfig(config_detail::readConfigFile(path), path);
}

std::string simulatorConfigYaml(const SimulatorOptions& o) {
  std::ostringstream y;
  const WorldOptions& w = o.world;
  const TrajectoryOptions& t = o.trajectory;
  const SemiDenseOptions& s = o.map.semi_dense;
  y << "seed: " << o.seed << "\nagents: " << o.agents << "\nmin_overlap: " << num(o.min_overlap) << "\n"
    << "camera: {fx: " << num(o.camera.fx) << ", fy: " << num(o.camera.fy) << ", cx: " << num(o.camera.cx)
    << ", cy: " << num(o.camera.cy) << ", width: " << o.camera.width << ", height: " << o.camera.height << "}\n"
    << "world:\n  room_length: " << num(w.room_length) << "\n  room_width: " << num(w.room_width)
    << "\n  room_height: " << num(w.room_height) << "\n  boxes: " << w.boxes << "\n  max_box_depth: " << num(w.max_box_depth)
    << "\n  max_wall_box_height: " << num(w.max_wall_box_height) << "\n  max_free_box_height: " << num(w.max_free_box_height)
    << "\n  free_box_wall_distance: " << num(w.free_box_wall_distance) << "\n  ambient: " << num(w.ambient)
    << "\n  texture: {texel: " << num(w.texture.texel) << ", min_shape_size: " << num(w.texture.min_shape_size)
    << ", max_shape_size: " << num(w.texture.max_shape_size) << ", coverage: " << num(w.texture.coverage)
    << ", detail_decay: " << num(w.texture.detail_decay) << ", blur: " << num(w.texture.blur) << "}\n"
    << "render: {supersampling: " << o.render.supersampling << ", image_noise: " << num(o.render.image_noise)
    << ", near: " << num(o.render.near) << "}\n"
    << "trajectory:\n  azimuth_span_deg: " << num(t.azimuth_span_deg) << "\n  distance: " << num(t.distance)
    << "\n  camera_height: " << num(t.camera_height) << "\n  target_height: " << num(t.target_height)
    << "\n  height_wobble: " << num(t.height_wobble) << "\n  yaw_wobble_deg: " << num(t.yaw_wobble_deg)
    << "\n  pitch_wobble_deg: " << num(t.pitch_wobble_deg) << "\n  roll_wobble_deg: " << num(t.roll_wobble_deg)
    << "\n  keyframe_distance: " << num(t.keyframe_distance) << "\n  keyframe_angle_deg: " << num(t.keyframe_angle_deg)
    << "\n  max_keyframes: " << t.max_keyframes << "\n  clearance: " << num(t.clearance) << "\n"
    << "layout: {overlap: " << num(o.layout.overlap) << ", view_angle_difference_deg: "
    << num(o.layout.view_angle_difference_deg) << ", first_azimuth_deg: " << num(o.layout.first_azimuth_deg) << "}\n"
    << "drift:\n  scale_drift: " << num(o.drift.scale_drift) << "\n  bend_deg: " << num(o.drift.bend_deg)
    << "\n  pose_noise_rotation_deg: " << num(o.drift.pose_noise_rotation_deg)
    << "\n  pose_noise_translation: " << num(o.drift.pose_noise_translation)
    << "\n  pose_noise_scale: " << num(o.drift.pose_noise_scale) << "\n  loop_closure: " << num(o.drift.loop_closure)
    << "\nmap:\n  cloud_fraction: " << num(o.map.cloud_fraction) << "\n  depth_images: " << o.map.depth_images
    << "\n  semi_dense: {min_gradient: " << num(s.min_gradient) << ", idepth_noise: " << num(s.idepth_noise)
    << ", reference_gradient: " << num(s.reference_gradient) << ", outlier_fraction: " << num(s.outlier_fraction)
    << ", subsample: " << s.subsample << ", noise_correlation: " << num(s.noise_correlation) << "}\n";
  if (o.per_agent.empty()) {
    y << "per_agent: []\n";
  } else {
    y << "per_agent:\n";
    for (const AgentOptions& a : o.per_agent) {
      y << "  - {name: \"" << a.name << "\"";
      optionalYaml(y, "scale", a.scale);
      optionalYaml(y, "azimuth_start_deg", a.azimuth_start_deg);
      optionalYaml(y, "azimuth_span_deg", a.azimuth_span_deg);
      optionalYaml(y, "view_angle_deg", a.view_angle_deg);
      optionalYaml(y, "scale_drift", a.scale_drift);
      optionalYaml(y, "bend_deg", a.bend_deg);
      y << "}\n";
    }
  }
  return y.str();
}

}  // namespace pcr_pro
