// The merge node (see merge_node.h).
#include "pcr_pro/ros/merge_node.h"

#include <cstdlib>
#include <sstream>

#include "pcr_pro/merge/merge_pipeline.h"
#include "pcr_pro/ros/msg_conversion.h"

namespace pcr_pro {
namespace ros_bridge {

namespace {

using Response = pcr_pro::MergeMaps::Response;

std::uint8_t statusCode(Status s) {
  switch (s) {
    case Status::kOk: return Response::OK;
    case Status::kNotEnoughMatches: return Response::NOT_ENOUGH_MATCHES;
    case Status::kRelativePoseFailed: return Response::RELATIVE_POSE_FAILED;
    case Status::kScaleFailed: return Response::SCALE_FAILED;
    case Status::kIcpNotConverged: return Response::ICP_NOT_CONVERGED;
    case Status::kDegenerate: return Response::DEGENERATE;
    case Status::kInvalidInput: return Response::INVALID_INPUT;
    case Status::kNoOverlap: return Response::NO_OVERLAP;
  }
  return Response::INVALID_INPUT;
}

Response answer(std::uint8_t code, const std::string& name, const std::string& message) {
  Response r;
  r.status = code;
  r.status_name = name;
  r.message = message;
  return r;
}

std::string joinIds(const std::vector<long>& ids) {
  std::ostringstream s;
  for (std::size_t i = 0; i < ids.size(); ++i) s << (i ? ", " : "") << ids[i];
  return s.str();
}

// Period of the per-(agent, topic) warnings about rejected or trimmed data [s].
constexpr double kWarnPeriod = 5.0;

}  // namespace

MergeNode::MergeNode(const ros::NodeHandle& nh, const ros::NodeHandle& pnh, NodeOptions options)
    : nh_(nh), pnh_(pnh), options_(std::move(options)), diagnostics_(nh_, pnh_) {
  fused_pub_ = pnh_.advertise<sensor_msgs::PointCloud2>("fused_cloud", 1, true);
  aligned_pub_ = pnh_.advertise<sensor_msgs::PointCloud2>("aligned_cloud", 1, true);
  edge_pub_ = pnh_.advertise<pcr_pro::MapEdge>("edge", 1, true);
  // The edge's rigid part and covariance as a standard message, for rviz.
  edge_pose_pub_ = pnh_.advertise<geometry_msgs::PoseWithCovarianceStamped>("edge_pose", 1, true);

  diagnostics_.setHardwareID("pcr_pro_merge");
  for (const AgentOptions& a : options_.agents) {
    auto agent = std::make_unique<Agent>();
    agent->options = a;
    agent->store = AgentStore(a.frame_id, options_.limits);
    Agent* raw = agent.get();
    const int q = options_.queue_size;
    if (options_.input == InputMode::kPcrPro) {
      agent->subscribers.push_back(nh_.subscribe<pcr_pro::Keyframe>(
          a.name + "/keyframes", q, [this, raw](const pcr_pro::Keyframe::ConstPtr& m) { onKeyframe(raw, m); }));
      agent->subscribers.push_back(nh_.subscribe<sensor_msgs::PointCloud2>(
          a.name + "/cloud", q, [this, raw](const sensor_msgs::PointCloud2::ConstPtr& m) { onCloud(raw, m); }));
    } else {
      agent->subscribers.push_back(nh_.subscribe<lsd_slam_viewer::keyframeMsg>(
          a.name + "/lsd_slam/keyframes", q,
          [this, raw](const lsd_slam_viewer::keyframeMsg::ConstPtr& m) { onLsdKeyframe(raw, m); }));
      agent->subscribers.push_back(nh_.subscribe<lsd_slam_viewer::keyframeGraphMsg>(
          a.name + "/lsd_slam/graph", q,
          [this, raw](const lsd_slam_viewer::keyframeGraphMsg::ConstPtr& m) { onLsdGraph(raw, m); }));
    }
    diagnostics_.add("agent " + a.name,
                     [this, raw](diagnostic_updater::DiagnosticStatusWrapper& s) { agentDiagnostics(raw, s); });
    agents_.push_back(std::move(agent));
  }
  diagnostics_.add("merge", [this](diagnostic_updater::DiagnosticStatusWrapper& s) { mergeDiagnostics(s); });
  diagnostics_timer_ = nh_.createTimer(ros::Duration(0.5), [this](const ros::TimerEvent&) { diagnostics_.update(); });

  worker_ = std::thread([this] { workerLoop(); });
  ros::AdvertiseServiceOptions service_options;
  service_options.init<pcr_pro::MergeMaps::Request, pcr_pro::MergeMaps::Response>(
      "merge", [this](pcr_pro::MergeMaps::Request& req, pcr_pro::MergeMaps::Response& res) {
        return onMergeService(req, res);
      });
  service_options.callback_queue = &service_queue_;
  merge_service_ = pnh_.advertiseService(service_options);
  service_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &service_queue_);
  service_spinner_->start();

  std::ostringstream agents;
  for (const AgentOptions& a : options_.agents) agents << " " << a.name << " (" << a.frame_id << ")";
  ROS_INFO("pcr_pro merge node: input %s, agents:%s; service %s; per agent at most %d keyframes and %d map points",
           inputModeName(options_.input), agents.str().c_str(), merge_service_.getService().c_str(),
           options_.limits.max_keyframes, options_.limits.max_cloud_points);
}

MergeNode::~MergeNode() {
  // The service thread may be waiting for the worker: stop the service first, then the worker.
  merge_service_.shutdown();
  if (service_spinner_) service_spinner_->stop();
  {
    std::lock_guard<std::mutex> lock(jobs_mutex_);
    stop_ = true;
  }
  jobs_cv_.notify_all();
  if (worker_.joinable()) worker_.join();
}

// --- data callbacks ---------------------------------------------------------------------------

void MergeNode::warnThrottled(Agent* agent, const std::string& key, const std::string& text) {
  Throttle& t = agent->throttles[key];
  const ros::WallTime now = ros::WallTime::now();
  if (!t.last.isZero() && (now - t.last).toSec() < kWarnPeriod) {
    ++t.suppressed;
    return;
  }
  if (t.suppressed > 0) {
    ROS_WARN("%s (and %zu more like it in the last %.0f s)", text.c_str(), t.suppressed, (now - t.last).toSec());
  } else {
    ROS_WARN("%s", text.c_str());
  }
  t.last = now;
  t.suppressed = 0;
}

void MergeNode::reject(Agent* agent, const std::string& topic, const std::string& what) {
  std::lock_guard<std::mutex> lock(agent->mutex);
  ++agent->rejected;
  agent->last_rejection = topic + ": " + what;
  warnThrottled(agent, "reject " + topic,
                "rejected a message on " + nh_.resolveName(topic) + " (agent " + agent->options.name + "): " + what);
}

void MergeNode::noteDropped(Agent* agent, const std::string& topic, long added, const std::vector<long>& dropped) {
  if (dropped.empty()) return;
  agent->keyframes_dropped += dropped.size();
  warnThrottled(agent, "drop " + topic,
                agent->options.name + ": max_keyframes_per_agent = " + std::to_string(options_.limits.max_keyframes) +
                    " reached: keyframe " + std::to_string(added) + " made the node drop keyframe(s) " +
                    joinIds(dropped) + ", received longest ago (" + std::to_string(agent->keyframes_dropped) +
                    " dropped so far)");
}

void MergeNode::noteCloudCap(Agent* agent, const std::string& what, const CloudCap& cap) {
  if (!cap.capped()) return;
  ++agent->clouds_voxelised;
  std::ostringstream s;
  s << what << ": " << cap.input_points << " points > max_cloud_points_per_agent = " << options_.limits.max_cloud_points
    << ": ";
  if (cap.subsampled) {
    s << "randomly subsampled to " << cap.kept_points << " points (the voxel grid could not reach the cap)";
  } else {
    s << "voxelised with leaf " << cap.leaf << " [map units] to " << cap.kept_points << " points";
  }
  warnThrottled(agent, "cap " + what, s.str());
}

void MergeNode::onKeyframe(Agent* agent, const pcr_pro::Keyframe::ConstPtr& msg) {
  const std::string topic = agent->options.name + "/keyframes";
  try {
    const DecodedKeyframe data = keyframeFromMsg(*msg);
    if (!data.frame_id.empty() && data.frame_id != agent->options.frame_id) {
      reject(agent, topic, "header.frame_id '" + printable(data.frame_id) + "' is not the agent's map frame '" +
                               agent->options.frame_id + "'");
      return;
    }
    std::lock_guard<std::mutex> lock(agent->mutex);
    const bool first = agent->store.keyframeCount() == 0;
    std::vector<long> dropped;
    const bool replaced = agent->store.setKeyframe(data.keyframe, data.camera, &dropped);
    ++agent->received;
    noteDropped(agent, topic, data.keyframe.id, dropped);
    if (first) ROS_INFO("%s: first keyframe (id %ld)", agent->options.name.c_str(), data.keyframe.id);
    ROS_DEBUG("%s: keyframe %ld %s", agent->options.name.c_str(), data.keyframe.id, replaced ? "replaced" : "added");
  } catch (const InputError& e) {
    reject(agent, topic, e.what());
  }
}

void MergeNode::onCloud(Agent* agent, const sensor_msgs::PointCloud2::ConstPtr& msg) {
  const std::string topic = agent->options.name + "/cloud";
  if (!msg->header.frame_id.empty() && msg->header.frame_id != agent->options.frame_id) {
    reject(agent, topic, "header.frame_id '" + printable(msg->header.frame_id) + "' is not the agent's map frame '" +
                             agent->options.frame_id + "'");
    return;
  }
  try {
    const Cloud cloud = cloudFromMsg(*msg);
    const std::uint64_t points = static_cast<std::uint64_t>(msg->width) * msg->height;
    const std::uint64_t nonfinite = points - static_cast<std::uint64_t>(cloud.cols());
    if (cloud.cols() == 0) {
      reject(agent, topic, "cloud: no finite point (" + std::to_string(nonfinite) + " of " + std::to_string(points) +
                               " points have a NaN/Inf coordinate)");
      return;
    }
    // The cap's voxel passes run outside the agent's lock.
    CloudCap cap;
    Cloud kept = capCloud(cloud, options_.limits.max_cloud_points, &cap);
    std::lock_guard<std::mutex> lock(agent->mutex);
    if (agent->store.cloudPoints() == 0) {
      ROS_INFO("%s: first map cloud (%ld points)", agent->options.name.c_str(), static_cast<long>(cloud.cols()));
    }
    agent->store.setCloud(std::move(kept));
    ++agent->received;
    if (nonfinite > 0) {
      agent->points_dropped_nonfinite += nonfinite;
      warnThrottled(agent, "nonfinite " + topic,
                    nh_.resolveName(topic) + " (agent " + agent->options.name + "): dropped " +
                        std::to_string(nonfinite) + " of " + std::to_string(points) +
                        " points with a NaN/Inf coordinate; kept the rest");
    }
    noteCloudCap(agent, nh_.resolveName(topic), cap);
  } catch (const InputError& e) {
    reject(agent, topic, e.what());
  }
}

void MergeNode::onLsdKeyframe(Agent* agent, const lsd_slam_viewer::keyframeMsg::ConstPtr& msg) {
  const std::string topic = agent->options.name + "/lsd_slam/keyframes";
  if (!msg->isKeyframe) {
    ROS_DEBUG_THROTTLE(5.0, "%s: ignoring a tracked (non-key) frame", topic.c_str());
    return;
  }
  try {
    const LsdKeyframe kf = lsdKeyframeFromMsg(*msg);
    std::lock_guard<std::mutex> lock(agent->mutex);
    const bool first = agent->store.keyframeCount() == 0;
    std::vector<long> dropped;
    const bool replaced = agent->store.setLsdKeyframe(kf, &dropped);
    ++agent->received;
    noteDropped(agent, topic, kf.id, dropped);
    if (first) ROS_INFO("%s: first LSD-SLAM keyframe (id %ld)", agent->options.name.c_str(), kf.id);
    ROS_DEBUG("%s: LSD-SLAM keyframe %ld %s", agent->options.name.c_str(), kf.id, replaced ? "replaced" : "added");
  } catch (const InputError& e) {
    reject(agent, topic, e.what());
  }
}

void MergeNode::onLsdGraph(Agent* agent, const lsd_slam_viewer::keyframeGraphMsg::ConstPtr& msg) {
  const std::string topic = agent->options.name + "/lsd_slam/graph";
  try {
    const LsdGraph graph = lsdGraphFromMsg(*msg);
    std::lock_guard<std::mutex> lock(agent->mutex);
    const int updated = agent->store.updateLsdPoses(graph.poses);
    ++agent->received;
    ++agent->graph_updates;
    ROS_DEBUG("%s: graph update moved %d of %zu keyframes", agent->options.name.c_str(), updated, graph.poses.size());
  } catch (const InputError& e) {
    reject(agent, topic, e.what());
  }
}

// --- the merge service ------------------------------------------------------------------------

bool MergeNode::onMergeService(pcr_pro::MergeMaps::Request& request, pcr_pro::MergeMaps::Response& response) {
  // Whatever goes wrong inside (e.g. std::bad_alloc), the caller gets an answer with a status.
  std::packaged_task<Response()> task([this, request] {
    try {
      return merge(request);
    } catch (const std::exception& e) {
      ROS_ERROR("merge failed with an exception: %s", e.what());
      return answer(Response::INVALID_INPUT, "INVALID_INPUT", std::string("the merge failed: ") + e.what());
    }
  });
  std::future<Response> result = task.get_future();
  {
    std::lock_guard<std::mutex> lock(jobs_mutex_);
    if (stop_) {
      response = answer(Response::INVALID_INPUT, "INVALID_INPUT", "the node is shutting down");
      return true;
    }
    jobs_.push_back(std::move(task));
  }
  jobs_cv_.notify_one();
  response = result.get();
  return true;  // the outcome is in response.status, never a bare false
}

void MergeNode::workerLoop() {
  for (;;) {
    std::packaged_task<Response()> task;
    {
      std::unique_lock<std::mutex> lock(jobs_mutex_);
      jobs_cv_.wait(lock, [this] { return stop_ || !jobs_.empty(); });
      if (jobs_.empty()) return;  // stop_ and nothing left
      task = std::move(jobs_.front());
      jobs_.pop_front();
    }
    task();
  }
}

Response MergeNode::merge(const pcr_pro::MergeMaps::Request& request) {
  const auto find = [this](const std::string& name) -> Agent* {
    for (const auto& a : agents_) {
      if (a->options.name == name) return a.get();
    }
    return nullptr;
  };
  // Names from the request are quoted only through printable(): they may hold anything.
  const std::string target_name =
      request.target_agent.empty() ? options_.agents[0].name : printable(request.target_agent, 200);
  const std::string source_name =
      request.source_agent.empty() ? options_.agents[1].name : printable(request.source_agent, 200);
  Agent* target = find(target_name);
  Agent* source = find(source_name);

  Response response;
  if (!target || !source) {
    std::ostringstream known;
    for (const AgentOptions& a : options_.agents) known << " " << a.name;
    response = answer(Response::UNKNOWN_AGENT, "UNKNOWN_AGENT",
                      "unknown agent '" + (target ? source_name : target_name) + "' (agents:" + known.str() + ")");
  } else if (target == source) {
    response = answer(Response::UNKNOWN_AGENT, "UNKNOWN_AGENT",
                      "source and target are the same agent '" + source_name + "'");
  } else {
    // Snapshot: copies of the stores (images are shared, never written in place).
    AgentStore source_copy, target_copy;
    std::string source_rejections, target_rejections;
    const auto rejections = [](const Agent& a) {
      if (a.rejected == 0) return std::string();
      return "; " + std::to_string(a.rejected) + " message(s) rejected, the last: " + a.last_rejection;
    };
    {
      std::lock_guard<std::mutex> lock(source->mutex);
      source_copy = source->store;
      source_rejections = rejections(*source);
    }
    {
      std::lock_guard<std::mutex> lock(target->mutex);
      target_copy = target->store;
      target_rejections = rejections(*target);
    }
    CloudCap source_cap, target_cap;
    const AgentMap source_map = source_copy.toAgentMap(options_.lsd, &source_cap);
    const AgentMap target_map = target_copy.toAgentMap(options_.lsd, &target_cap);
    for (const auto& [agent, cap] : {std::pair{source, &source_cap}, std::pair{target, &target_cap}}) {
      std::lock_guard<std::mutex> lock(agent->mutex);
      noteCloudCap(agent, agent->options.name + ": LSD-SLAM map cloud", *cap);
    }
    const bool lsd = options_.input == InputMode::kLsdSlam;
    std::string missing;
    for (const auto& [agent, map, why] : {std::tuple{target, &target_map, &target_rejections},
                                          std::tuple{source, &source_map, &source_rejections}}) {
      if (!missing.empty()) break;
      const std::string& n = agent->options.name;
      if (map->keyframes.empty()) {
        missing = n + ": no keyframe received yet (topic " + n + (lsd ? "/lsd_slam/keyframes)" : "/keyframes)") + *why;
      } else if (map->cloud.cols() == 0) {
        missing = lsd ? n + ": no point of its LSD-SLAM keyframes passes the lsd/ filters" + *why
                      : n + ": no map cloud received yet (topic " + n + "/cloud)" + *why;
      }
    }
    MergeRequest merge_request;
    if (request.source_keyframe >= 0) merge_request.source_keyframe = request.source_keyframe;
    if (request.target_keyframe >= 0) merge_request.target_keyframe = request.target_keyframe;
    std::string unknown_keyframe;
    for (const auto& [id, store, name] : {std::tuple{merge_request.source_keyframe, &source_copy, source_name},
                                          std::tuple{merge_request.target_keyframe, &target_copy, target_name}}) {
      Sim3 unused;
      if (id && !store->keyframePose(*id, &unused)) {
        unknown_keyframe = name + " has no keyframe " + std::to_string(*id) + " (has: " + joinIds(store->keyframeIds()) + ")";
      }
    }
    if (!missing.empty()) {
      response = answer(Response::NO_DATA, "NO_DATA", missing);
    } else if (!unknown_keyframe.empty()) {
      response = answer(Response::UNKNOWN_KEYFRAME, "UNKNOWN_KEYFRAME", unknown_keyframe);
    } else {
      ROS_INFO("merging %s (%zu keyframes, %ld points) into %s (%zu keyframes, %ld points)", source_name.c_str(),
               source_map.keyframes.size(), static_cast<long>(source_map.cloud.cols()), target_name.c_str(),
               target_map.keyframes.size(), static_cast<long>(target_map.cloud.cols()));
      std::srand(1);  // OpenCV's FLANN draws from std::rand(): the same data gives the same merge
      MergeResult result;
      try {
        result = mergeMaps(source_map, target_map, merge_request, options_.merge);
      } catch (const std::exception& e) {
        result.report.status = Status::kInvalidInput;
        result.report.message = e.what();
      }
      const RegistrationReport& r = result.report;
      response = answer(statusCode(r.status), statusName(r.status), r.message);
      if (r.status == Status::kOk && r.transform && r.covariance) {
        const ros::Time stamp = ros::Time::now();
        const EdgeNames names{source_name, target_name, source->options.frame_id, target->options.frame_id};
        response.edge = edgeToMsg(r, names, stamp);
        edge_pub_.publish(response.edge);
        geometry_msgs::PoseWithCovarianceStamped edge_pose;
        edge_pose.header = response.edge.header;
        edge_pose.pose = response.edge.pose;
        edge_pose_pub_.publish(edge_pose);
        const Sim3& s = *r.transform;
        Cloud fused(3, target_map.cloud.cols() + source_map.cloud.cols());
        fused << target_map.cloud, s.apply(source_map.cloud);
        fused_pub_.publish(cloudToMsg(fused, names.target_frame, stamp));
        // In the source frame, scaled: the rigid tf target -> source puts it onto the target.
        aligned_pub_.publish(cloudToMsg(source_map.cloud * s.scale(), names.source_frame, stamp));
        if (options_.publish_tf) {
          static_tf_.sendTransform(rigidTransformToMsg(s, names.target_frame, names.source_frame, stamp));
        }
        ROS_INFO("merged %s into %s: scale %.5g +- %.2g, t [%.4g %.4g %.4g], keyframes %ld -> %ld, fitness %.4g, %d "
                 "correspondences",
                 source_name.c_str(), target_name.c_str(), s.scale(), response.edge.scale_stddev, s.translation().x(),
                 s.translation().y(), s.translation().z(), static_cast<long>(response.edge.source_keyframe),
                 static_cast<long>(response.edge.target_keyframe), response.edge.fitness_rmse,
                 response.edge.correspondences);
      }
    }
  }
  if (response.status != Response::OK) {
    ROS_INFO("merge %s -> %s: %s: %s", source_name.c_str(), target_name.c_str(), response.status_name.c_str(),
             response.message.c_str());
  }
  std::lock_guard<std::mutex> lock(merge_state_mutex_);
  merge_state_.attempted = true;
  merge_state_.status = response.status_name;
  merge_state_.message = response.message;
  (response.status == Response::OK ? merge_state_.merges_ok : merge_state_.merges_failed)++;
  return response;
}

// --- diagnostics ------------------------------------------------------------------------------

void MergeNode::agentDiagnostics(Agent* agent, diagnostic_updater::DiagnosticStatusWrapper& s) {
  std::lock_guard<std::mutex> lock(agent->mutex);
  const AgentStore& st = agent->store;
  const bool lsd = options_.input == InputMode::kLsdSlam;
  const bool has_data = st.keyframeCount() > 0 && (lsd || st.cloudPoints() > 0);
  if (!has_data) {
    s.summary(diagnostic_msgs::DiagnosticStatus::WARN, "waiting for data");
  } else if (agent->rejected > 0) {
    s.summary(diagnostic_msgs::DiagnosticStatus::WARN, "receiving; some messages were rejected");
  } else {
    s.summary(diagnostic_msgs::DiagnosticStatus::OK, "receiving");
  }
  s.add("frame_id", agent->options.frame_id);
  s.add("keyframes", st.keyframeCount());
  s.add("keyframe_ids", joinIds(st.keyframeIds()));
  if (!lsd) s.add("cloud_points", st.cloudPoints());
  if (lsd) s.add("graph_updates", agent->graph_updates);
  s.add("messages_received", agent->received);
  s.add("messages_rejected", agent->rejected);
  s.add("last_rejection", agent->last_rejection);
  s.add("keyframes_dropped", agent->keyframes_dropped);
  s.add("clouds_voxelised", agent->clouds_voxelised);
  s.add("points_dropped_nonfinite", agent->points_dropped_nonfinite);
}

void MergeNode::mergeDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& s) {
  std::lock_guard<std::mutex> lock(merge_state_mutex_);
  const bool ok = !merge_state_.attempted || merge_state_.status == "OK";
  s.summary(ok ? diagnostic_msgs::DiagnosticStatus::OK : diagnostic_msgs::DiagnosticStatus::WARN,
            merge_state_.status + ": " + merge_state_.message);
  s.add("last_status", merge_state_.status);
  s.add("merges_ok", merge_state_.merges_ok);
  s.add("merges_failed", merge_state_.merges_failed);
}

}  // namespace ros_bridge
}  // namespace pcr_pro
