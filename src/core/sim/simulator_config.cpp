// SimulatorOptions: validation, YAML parsing (config/simulator.yaml) and YAML output.
#include <yaml-cpp/yaml.h>

#include <cctype>
#include <cmath>
#include <cstdlib>
#include <set>
#include <sstream>

#include "io/yaml_block.h"
#include "pcr_pro/io/bundle.h"
#include "pcr_pro/io/text_escape.h"
#include "pcr_pro/sim/simulator.h"

namespace pcr_pro {
namespace {

using config_detail::Block;

// Shortest decimal text that reads back to the same double.
std::string num(double v) { return schema_detail::numberText(v); }

void range(const std::string& key, double v, double lo, double hi) {
  if (!(v >= lo && v <= hi)) throw InputError(key + ": must be in [" + num(lo) + ", " + num(hi) + "], got " + num(v));
}

}  // namespace

// The simulator's own schemas stay private to this file: nothing else binds or prints them. The
// ranges that depend on other values (camera_height, target_height) are checked by validate().
// The camera block binds through the bundle's camera schema (bundle.h); world, world.texture,
// render and map.semi_dense through the schemas beside their validate() (world.h, render.h,
// semi_dense.h).
template <>
const ParamSchema<SimulatorOptions>& paramSchema<SimulatorOptions>() {
  using O = SimulatorOptions;
  static const ParamSchema<O> schema{"", {
      {"seed", &O::seed, ParamRange::any(), "", "seed of every random draw of the simulation"},
      {"agents", &O::agents, ParamRange::closed(1, 26), "", "number of agents"},
      {"min_overlap", &O::min_overlap, ParamRange::closed(0, 1), "-",
       "pairs whose overlap is below this count as not overlapping in the truth"},
  }, ParamMessage::kNode};
  return schema;
}

template <>
const ParamSchema<TrajectoryOptions>& paramSchema<TrajectoryOptions>() {
  using O = TrajectoryOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"trajectory", {
      {"azimuth_span_deg", &O::azimuth_span_deg, R::closed(1, 360), "deg", "azimuth range an agent sweeps"},
      {"distance", &O::distance, R::closed(0.5, 20), "m", "camera to looked-at wall point"},
      {"camera_height", &O::camera_height, R::any(), "m", "camera height, clear of floor and ceiling"},
      {"target_height", &O::target_height, R::any(), "m", "height of the looked-at point, in the room"},
      {"height_wobble", &O::height_wobble, R::closed(0, 2), "m", "amplitude of the camera height variation"},
      {"yaw_wobble_deg", &O::yaw_wobble_deg, R::closed(0, 45), "deg", "amplitude of the yaw variation"},
      {"pitch_wobble_deg", &O::pitch_wobble_deg, R::closed(0, 45), "deg", "amplitude of the pitch variation"},
      {"roll_wobble_deg", &O::roll_wobble_deg, R::closed(0, 45), "deg", "amplitude of the roll variation"},
      {"keyframe_distance", &O::keyframe_distance, R::closed(1e-3, 100), "m", "a new keyframe after this much motion"},
      {"keyframe_angle_deg", &O::keyframe_angle_deg, R::closed(0.1, 180), "deg", "... or this much rotation"},
      {"max_keyframes", &O::max_keyframes, R::closed(2, 1000), "", "keyframes per agent at most"},
      {"clearance", &O::clearance, R::closed(0, 2), "m", "smallest distance of a camera from walls and boxes"},
  }, ParamMessage::kNode};
  return schema;
}

template <>
const ParamSchema<LayoutOptions>& paramSchema<LayoutOptions>() {
  using O = LayoutOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"layout", {
      {"overlap", &O::overlap, R::closed(0, 1), "-", "overlap of agent_b with agent_a"},
      {"view_angle_difference_deg", &O::view_angle_difference_deg, R::closed(0, 120), "deg",
       "view-angle difference of agent_b to agent_a about the vertical"},
      {"first_azimuth_deg", &O::first_azimuth_deg, R::closed(-720, 720), "deg", "azimuth where agent_a starts"},
  }, ParamMessage::kNode};
  return schema;
}

template <>
const ParamSchema<DriftOptions>& paramSchema<DriftOptions>() {
  using O = DriftOptions;
  using R = ParamRange;
  static const ParamSchema<O> schema{"drift", {
      {"scale_drift", &O::scale_drift, R::closed(-0.5, 0.5), "-", "relative scale change from the first to the last keyframe"},
      {"bend_deg", &O::bend_deg, R::closed(-45, 45), "deg", "rotation drift about the vertical over the path"},
      {"pose_noise_rotation_deg", &O::pose_noise_rotation_deg, R::closed(0, 30), "deg", "per-keyframe rotation jitter"},
      {"pose_noise_translation", &O::pose_noise_translation, R::closed(0, 10), "m", "per-keyframe translation jitter"},
      {"pose_noise_scale", &O::pose_noise_scale, R::closed(0, 0.5), "-", "per-keyframe relative scale jitter"},
      {"loop_closure", &O::loop_closure, R::closed(0, 1), "-", "fraction of the drift a final graph update removes"},
  }, ParamMessage::kNode};
  return schema;
}

template <>
const ParamSchema<MapOutputOptions>& paramSchema<MapOutputOptions>() {
  using O = MapOutputOptions;
  static const ParamSchema<O> schema{"map", {
      {"cloud_fraction", &O::cloud_fraction, ParamRange::closed(1e-6, 1), "-",
       "fraction of each keyframe's semi-dense points that go into the map cloud"},
      {"depth_images",
       TextParam<O>{+[](const O& o) { return o.depth_images; },
                    +[](O* o, const std::string& s) {
                      o->depth_images = s;
                      return s == "dense" || s == "semi_dense" || s == "none";
                    },
                    "dense, semi_dense or none"},
       ParamRange::any(), "", "depth images of the bundles and keyframes"},
  }, ParamMessage::kNode};
  return schema;
}

namespace {

// The ranges of the trajectory that depend on the world (the others are the schema's).
void validateTrajectory(const TrajectoryOptions& t, const WorldOptions& w) {
  checkRanges(paramSchema<TrajectoryOptions>(), t);
  range("trajectory.camera_height", t.camera_height, t.clearance + t.height_wobble,
        w.room_height - t.clearance - t.height_wobble);
  range("trajectory.target_height", t.target_height, 0.0, w.room_height);
}

void validateDrift(const std::string& prefix, double scale_drift, double bend_deg) {
  range(prefix + "scale_drift", scale_drift, -0.5, 0.5);
  range(prefix + "bend_deg", bend_deg, -45.0, 45.0);
}

void validateCamera(const PinholeCamera& c, const std::string& key) {
  if (!c.valid() || c.width > 4096 || c.height > 4096 || c.width < 16 || c.height < 16) {
    throw InputError(key + ": fx, fy must be finite and > 0, width and height in [16, 4096]");
  }
}

void validateAgent(const AgentOptions& a, std::size_t i) {
  const std::string f = "per_agent[" + std::to_string(i) + "].";
  if (!a.name.empty()) {
    for (char c : a.name) {
      if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_')) {
        throw InputError(f + "name: only letters, digits and '_' (it names a directory and ROS topics), got '" + printable(a.name) + "'");
      }
    }
  }
  if (a.scale) range(f + "scale", *a.scale, 1e-3, 1e3);
  if (a.azimuth_start_deg) range(f + "azimuth_start_deg", *a.azimuth_start_deg, -720.0, 720.0);
  if (a.azimuth_span_deg) range(f + "azimuth_span_deg", *a.azimuth_span_deg, 1.0, 360.0);
  if (a.view_angle_deg) range(f + "view_angle_deg", *a.view_angle_deg, -60.0, 60.0);
  validateDrift(f, a.scale_drift.value_or(0.0), a.bend_deg.value_or(0.0));
  if (a.idepth_noise && !(*a.idepth_noise >= 0.0 && std::isfinite(*a.idepth_noise))) {
    throw InputError(f + "idepth_noise: must be >= 0 and finite, got " + num(*a.idepth_noise));
  }
  if (a.camera) validateCamera(*a.camera, f + "camera");
}

void optionalDouble(Block* b, const std::string& key, std::optional<double>* v) {
  const YAML::Node value = b->child(key);  // marks the key as known
  if (value) *v = b->reader().number(value, b->keyPath(key));
}

// Binds the block `key` of parent through O's schema; nested(block) binds its sub-blocks.
template <typename O, typename Nested>
void bindBlock(Block* parent, const std::string& key, O* o, Nested&& nested) {
  Block b(parent->reader(), parent->child(key), parent->keyPath(key));
  config_detail::bindParams(paramSchema<O>(), &b, o);
  nested(&b);
  b.finish();
}

template <typename O>
void bindBlock(Block* parent, const std::string& key, O* o) {
  bindBlock(parent, key, o, [](Block*) {});
}

void loadAgents(Block* top, const PinholeCamera& camera, std::vector<AgentOptions>* agents) {
  const YAML::Node node = top->child("per_agent");
  if (!node || node.IsNull()) return;
  top->reader().list(node, "per_agent", "agents");
  for (std::size_t i = 0; i < node.size(); ++i) {
    Block b(top->reader(), node[i], yaml_detail::elementKey("per_agent", i));
    AgentOptions a;
    b.get("name", &a.name);
    optionalDouble(&b, "scale", &a.scale);
    optionalDouble(&b, "azimuth_start_deg", &a.azimuth_start_deg);
    optionalDouble(&b, "azimuth_span_deg", &a.azimuth_span_deg);
    optionalDouble(&b, "view_angle_deg", &a.view_angle_deg);
    optionalDouble(&b, "scale_drift", &a.scale_drift);
    optionalDouble(&b, "bend_deg", &a.bend_deg);
    optionalDouble(&b, "idepth_noise", &a.idepth_noise);
    if (b.child("camera")) {
      PinholeCamera own = camera;  // keys not given: the top-level camera's
      bindBlock(&b, "camera", &own);
      a.camera = own;
    }
    b.finish();
    agents->push_back(a);
  }
}

std::string cameraYaml(const PinholeCamera& c) {
  return "{fx: " + num(c.fx) + ", fy: " + num(c.fy) + ", cx: " + num(c.cx) + ", cy: " + num(c.cy) +
         ", width: " + std::to_string(c.width) + ", height: " + std::to_string(c.height) + "}";
}

void optionalYaml(std::ostringstream& y, const char* key, const std::optional<double>& v) {
  if (v) y << ", " << key << ": " << num(*v);
}

}  // namespace

void validate(const SimulatorOptions& o) {
  checkRanges(paramSchema<SimulatorOptions>(), o);
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
  validateCamera(o.camera, "camera");
  validate(o.world);
  validate(o.render);
  validateTrajectory(o.trajectory, o.world);
  checkRanges(paramSchema<LayoutOptions>(), o.layout);
  checkRanges(paramSchema<DriftOptions>(), o.drift);
  try {
    validate(o.map.semi_dense);
  } catch (const InputError& e) {
    throw InputError(std::string("map.") + e.what());
  }
  checkRanges(paramSchema<MapOutputOptions>(), o.map);
  if (o.map.depth_images != "dense" && o.map.depth_images != "semi_dense" && o.map.depth_images != "none") {
    throw InputError("map.depth_images: must be dense, semi_dense or none, got '" + o.map.depth_images + "'");
  }
}

SimulatorOptions parseSimulatorConfig(const std::string& text, const std::string& origin) {
  SimulatorOptions o;
  config_detail::loadTopLevel(text, origin, [&o](Block* top) {
    config_detail::bindParams(paramSchema<SimulatorOptions>(), top, &o);
    bindBlock(top, "camera", &o.camera);
    bindBlock(top, "world", &o.world, [&o](Block* world) { bindBlock(world, "texture", &o.world.texture); });
    bindBlock(top, "render", &o.render);
    bindBlock(top, "trajectory", &o.trajectory);
    bindBlock(top, "layout", &o.layout);
    bindBlock(top, "drift", &o.drift);
    bindBlock(top, "map", &o.map, [&o](Block* map) { bindBlock(map, "semi_dense", &o.map.semi_dense); });
    loadAgents(top, o.camera, &o.per_agent);
  });
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
    << "camera: " << cameraYaml(o.camera) << "\n"
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
      optionalYaml(y, "idepth_noise", a.idepth_noise);
      if (a.camera) y << ", camera: " << cameraYaml(*a.camera);
      y << "}\n";
    }
  }
  return y.str();
}

}  // namespace pcr_pro
