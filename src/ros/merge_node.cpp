// The merge node (see merge_node.h).
#include "pcr_pro/ros/merge_node.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <future>
#include <sstream>
#include <tuple>

#include "pcr_pro/io/pose_graph.h"
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
    case Status::kInconsistent: return Response::INCONSISTENT;
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

using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
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
    : nh_(nh),
      pnh_(pnh),
      options_(std::move(options)),
      pipeline_(std::make_unique<MergePipeline>(options_.merge)),
      diagnostics_(nh_, pnh_) {
  fused_pub_ = pnh_.advertise<sensor_msgs::PointCloud2>("fused_cloud", 1, true);
  aligned_pub_ = pnh_.advertise<sensor_msgs::PointCloud2>("aligned_cloud", 1, true);
  edge_pub_ = pnh_.advertise<pcr_pro::MapEdge>("edge", 1, true);
  // The edge's rigid part and covariance as a standard message, for rviz.
  edge_pose_pub_ = pnh_.advertise<geometry_msgs::PoseWithCovarianceStamped>("edge_pose", 1, true);
  // Every successful edge so far, for a late subscriber (a pose-graph optimiser).
  history_pub_ = pnh_.advertise<pcr_pro::EdgeHistory>("edge_history", 1, true);
  history_pub_.publish(pcr_pro::EdgeHistory());

  diagnostics_.setHardwareID("pcr_pro_merge");
  std::vector<std::string> sources;
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
    if (a.name != options_.autoMergeTarget()) sources.push_back(a.name);
    agents_.push_back(std::move(agent));
  }
  diagnostics_.add("merge", [this](diagnostic_updater::DiagnosticStatusWrapper& s) { mergeDiagnostics(s); });
  diagnostics_timer_ = nh_.createTimer(ros::Duration(options_.diagnostic_period),
                                       [this](const ros::TimerEvent&) { diagnostics_.force_update(); });
  schedule_ = std::make_unique<AutoMergeSchedule>(options_.auto_merge, options_.autoMergeTarget(), sources);

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
  // Quick (a copy of the history): on the node's own queue.
  edges_service_ = pnh_.advertiseService("edges", &MergeNode::onEdgesService, this);
  if (options_.auto_merge.enabled) {
    auto_merge_timer_ = nh_.createTimer(ros::Duration(options_.auto_merge.period),
                                        [this](const ros::TimerEvent&) { checkAutoMerge(); });
  }

  std::ostringstream agents;
  for (const AgentOptions& a : options_.agents) agents << " " << a.name << " (" << a.frame_id << ")";
  ROS_INFO("pcr_pro merge node: input %s, agents:%s; service %s; per agent at most %d keyframes and %d map points; "
           "seed %ld",
           inputModeName(options_.input), agents.str().c_str(), merge_service_.getService().c_str(),
           options_.limits.max_keyframes, options_.limits.max_cloud_points, static_cast<long>(options_.seed));
  if (options_.auto_merge.enabled) {
    ROS_INFO("automatic merging into %s: once both maps have %d keyframes, again after %d new keyframes%s; checked "
             "every %.3g s",
             options_.autoMergeTarget().c_str(), options_.auto_merge.min_keyframes, options_.auto_merge.new_keyframes,
             options_.auto_merge.after_graph_update ? " or when keyframes moved" : "", options_.auto_merge.period);
  }
}

MergeNode::~MergeNode() {
  // The service thread may be waiting for the worker: stop the services and timers first, then the worker.
  auto_merge_timer_.stop();
  merge_service_.shutdown();
  edges_service_.shutdown();
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

void MergeNode::noteKeyframe(Agent* agent, bool replaced) {
  if (replaced) {
    ++agent->keyframe_moves;
  } else {
    ++agent->keyframes_added;
  }
}

MapProgress MergeNode::progress(const Agent& agent) const {
  MapProgress p;
  p.keyframes = agent.store.keyframeCount();
  p.has_cloud = options_.input == InputMode::kLsdSlam ? p.keyframes > 0 : agent.store.cloudPoints() > 0;
  p.added = agent.keyframes_added;
  p.moved = agent.keyframe_moves;
  return p;
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
    noteKeyframe(agent, replaced);
    noteDropped(agent, topic, data.keyframe.id, dropped);
    forgetFeatures(*agent, data.keyframe.id, replaced, dropped);
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
    noteKeyframe(agent, replaced);
    noteDropped(agent, topic, kf.id, dropped);
    forgetFeatures(*agent, kf.id, replaced, dropped);
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
    if (updated > 0) ++agent->keyframe_moves;
    ROS_DEBUG("%s: graph update moved %d of %zu keyframes", agent->options.name.c_str(), updated, graph.poses.size());
  } catch (const InputError& e) {
    reject(agent, topic, e.what());
  }
}

// --- the services and automatic merging ---------------------------------------------------------

bool MergeNode::onMergeService(pcr_pro::MergeMaps::Request& request, pcr_pro::MergeMaps::Response& response) {
  // Names from the request are quoted only through printable(): they may hold anything.
  MergeJob job;
  job.trigger = "service";
  job.target = request.target_agent.empty() ? options_.agents[0].name : printable(request.target_agent, 200);
  job.source = request.source_agent.empty() ? options_.agents[1].name : printable(request.source_agent, 200);
  // A keyframe id counts only with its flag: an empty request (ids 0) lets the pipeline choose,
  // and an id without its flag is refused rather than silently ignored.
  for (const auto& [use, id, field, out] :
       {std::tuple{request.use_source_keyframe, request.source_keyframe, "source", &job.keyframes.source_keyframe},
        std::tuple{request.use_target_keyframe, request.target_keyframe, "target", &job.keyframes.target_keyframe}}) {
    if (use) {
      *out = static_cast<long>(id);
    } else if (id != 0) {
      const std::string f = field;
      response = answer(Response::INVALID_INPUT, "INVALID_INPUT",
                        f + "_keyframe is " + std::to_string(id) + " but use_" + f + "_keyframe is false: set use_" + f +
                            "_keyframe: true to merge from keyframe " + std::to_string(id) + ", or leave " + f +
                            "_keyframe out to let the pipeline choose");
      noteOutcome(job, response);
      return true;
    }
  }
  // Whatever goes wrong inside (e.g. std::bad_alloc), the caller gets an answer with a status.
  auto task = std::make_shared<std::packaged_task<Response()>>([this, job] {
    try {
      return merge(job);
    } catch (const std::exception& e) {
      ROS_ERROR("merge failed with an exception: %s", e.what());
      return answer(Response::INVALID_INPUT, "INVALID_INPUT", std::string("the merge failed: ") + e.what());
    }
  });
  std::future<Response> result = task->get_future();
  if (!enqueue([task] { (*task)(); })) {
    response = answer(Response::INVALID_INPUT, "INVALID_INPUT", "the node is shutting down");
    return true;
  }
  response = result.get();
  return true;  // the outcome is in response.status, never a bare false
}

bool MergeNode::onEdgesService(pcr_pro::GetEdges::Request& request, pcr_pro::GetEdges::Response& response) {
  std::string unknown;
  for (const std::string& name : {request.source_agent, request.target_agent}) {
    if (!name.empty() && !findAgent(name)) unknown += (unknown.empty() ? "" : ", ") + printable(name, 200);
  }
  {
    std::lock_guard<std::mutex> lock(history_mutex_);
    for (const pcr_pro::MergeRecord& r : history_) {
      if ((request.source_agent.empty() || r.edge.source_agent == request.source_agent) &&
          (request.target_agent.empty() || r.edge.target_agent == request.target_agent)) {
        response.records.push_back(r);
      }
    }
  }
  response.message = std::to_string(response.records.size()) + " edge(s)";
  if (!unknown.empty()) response.message += "; unknown agent(s): " + unknown;
  return true;
}

void MergeNode::checkAutoMerge() {
  {
    std::lock_guard<std::mutex> lock(auto_mutex_);
    if (auto_pending_) return;  // one automatic merge at a time, and never a backlog of them
  }
  std::map<std::string, MapProgress> now;
  for (const auto& a : agents_) {
    std::lock_guard<std::mutex> lock(a->mutex);
    now[a->options.name] = progress(*a);
  }
  MergeJob job;
  job.trigger = "auto";
  {
    std::lock_guard<std::mutex> lock(auto_mutex_);
    const DueMerge due = schedule_->due(now);
    if (due.source.empty()) return;
    job.source = due.source;
    job.target = schedule_->target();
    auto_pending_ = true;
    ROS_INFO("automatic merge of %s into %s: %s", job.source.c_str(), job.target.c_str(), due.reason.c_str());
  }
  const bool queued = enqueue([this, job] {
    try {
      merge(job);
    } catch (const std::exception& e) {
      ROS_ERROR("automatic merge failed with an exception: %s", e.what());
    }
    std::lock_guard<std::mutex> lock(auto_mutex_);
    auto_pending_ = false;
  });
  if (!queued) {
    std::lock_guard<std::mutex> lock(auto_mutex_);
    auto_pending_ = false;
  }
}

bool MergeNode::enqueue(std::function<void()> job) {
  {
    std::lock_guard<std::mutex> lock(jobs_mutex_);
    if (stop_) return false;
    jobs_.push_back(std::move(job));
  }
  jobs_cv_.notify_one();
  return true;
}

void MergeNode::workerLoop() {
  for (;;) {
    std::function<void()> job;
    {
      std::unique_lock<std::mutex> lock(jobs_mutex_);
      jobs_cv_.wait(lock, [this] { return stop_ || !jobs_.empty(); });
      if (jobs_.empty()) return;  // stop_ and nothing left
      job = std::move(jobs_.front());
      jobs_.pop_front();
    }
    job();
  }
}

// --- one merge (on the worker) --------------------------------------------------------------------

MergeNode::Agent* MergeNode::findAgent(const std::string& name) const {
  for (const auto& a : agents_) {
    if (a->options.name == name) return a.get();
  }
  return nullptr;
}

MergeNode::Snapshot MergeNode::takeSnapshot(Agent* agent) const {
  Snapshot s;
  s.agent = agent;
  std::lock_guard<std::mutex> lock(agent->mutex);
  s.store = agent->store;  // images are shared, never written in place
  if (agent->rejected > 0) {
    s.rejections = "; " + std::to_string(agent->rejected) + " message(s) rejected, the last: " + agent->last_rejection;
  }
  s.progress = progress(*agent);
  return s;
}

std::optional<Response> MergeNode::checkData(const MergeJob& job, const Snapshot& source, const AgentMap& source_map,
                                             const Snapshot& target, const AgentMap& target_map) const {
  const bool lsd = options_.input == InputMode::kLsdSlam;
  for (const auto& [snapshot, map] : {std::pair{&target, &target_map}, std::pair{&source, &source_map}}) {
    const std::string& n = snapshot->agent->options.name;
    if (map->keyframes.empty()) {
      return answer(Response::NO_DATA, "NO_DATA",
                    n + ": no keyframe received yet (topic " + n + (lsd ? "/lsd_slam/keyframes)" : "/keyframes)") +
                        snapshot->rejections);
    }
    if (map->cloud.cols() == 0) {
      return answer(Response::NO_DATA, "NO_DATA",
                    lsd ? n + ": no point of its LSD-SLAM keyframes passes the lsd/ filters" + snapshot->rejections
                        : n + ": no map cloud received yet (topic " + n + "/cloud)" + snapshot->rejections);
    }
  }
  // A given keyframe id is taken at its word: negative ids and ids the agent lacks are refused.
  for (const auto& [id, snapshot] : {std::pair{job.keyframes.source_keyframe, &source},
                                     std::pair{job.keyframes.target_keyframe, &target}}) {
    Sim3 unused;
    if (id && !snapshot->store.keyframePose(*id, &unused)) {
      return answer(Response::UNKNOWN_KEYFRAME, "UNKNOWN_KEYFRAME",
                    snapshot->agent->options.name + " has no keyframe " + std::to_string(*id) +
                        " (has: " + joinIds(snapshot->store.keyframeIds()) + ")");
    }
  }
  return std::nullopt;
}

MergeResult MergeNode::runPipeline(const AgentMap& source, const std::string& source_agent, const AgentMap& target,
                                   const std::string& target_agent, const MergeRequest& request) {
  return pipeline_->merge(source, target, request, source_agent, target_agent);
}

void MergeNode::forgetFeatures(const Agent& agent, long replaced_id, bool replaced, const std::vector<long>& dropped) {
  // The cache also checks each keyframe's image content; this keeps it from holding stale entries.
  if (replaced) pipeline_->featureCache().invalidate(agent.options.name, replaced_id);
  for (long id : dropped) pipeline_->featureCache().invalidate(agent.options.name, id);
}

Response MergeNode::merge(const MergeJob& job) {
  const Clock::time_point start = Clock::now();
  Agent* target = findAgent(job.target);
  Agent* source = findAgent(job.source);
  if (!target || !source) {
    std::ostringstream known;
    for (const AgentOptions& a : options_.agents) known << " " << a.name;
    const Response response = answer(Response::UNKNOWN_AGENT, "UNKNOWN_AGENT",
                                      "unknown agent '" + (target ? job.source : job.target) + "' (agents:" +
                                          known.str() + ")");
    noteOutcome(job, response);
    return response;
  }
  if (target == source) {
    const Response response =
        answer(Response::UNKNOWN_AGENT, "UNKNOWN_AGENT", "source and target are the same agent '" + job.source + "'");
    noteOutcome(job, response);
    return response;
  }
  const Snapshot s = takeSnapshot(source), t = takeSnapshot(target);
  CloudCap source_cap, target_cap;
  const AgentMap source_map = s.store.toAgentMap(options_.lsd, &source_cap);
  const AgentMap target_map = t.store.toAgentMap(options_.lsd, &target_cap);
  for (const auto& [agent, cap] : {std::pair{source, &source_cap}, std::pair{target, &target_cap}}) {
    std::lock_guard<std::mutex> lock(agent->mutex);
    noteCloudCap(agent, agent->options.name + ": LSD-SLAM map cloud", *cap);
  }
  const std::optional<Response> refused = checkData(job, s, source_map, t, target_map);
  if (job.target == options_.autoMergeTarget() && (!refused || job.trigger == "auto")) {
    std::lock_guard<std::mutex> lock(auto_mutex_);
    schedule_->attempted(job.source, s.progress, t.progress);
  }
  if (refused) {
    noteOutcome(job, *refused);
    return *refused;
  }
  MergeTiming timing;
  timing.maps_ms = msSince(start);
  const Response response = mergeMaps(job, s, source_map, t, target_map, &timing);
  timing.total_ms = msSince(start);
  noteOutcome(job, response, timing);
  return response;
}

Response MergeNode::mergeMaps(const MergeJob& job, const Snapshot& s, const AgentMap& source_map, const Snapshot& t,
                              const AgentMap& target_map, MergeTiming* timing) {
  ROS_INFO("merging %s (%zu keyframes, %ld points) into %s (%zu keyframes, %ld points), %s", job.source.c_str(),
           source_map.keyframes.size(), static_cast<long>(source_map.cloud.cols()), job.target.c_str(),
           target_map.keyframes.size(), static_cast<long>(target_map.cloud.cols()), job.trigger.c_str());
  MergeResult result;
  try {
    result = runPipeline(source_map, job.source, target_map, job.target, job.keyframes);
  } catch (const std::exception& e) {
    result.report.status = Status::kInvalidInput;
    result.report.message = e.what();
  }
  timing->stages = result.report.timings;
  timing->features_computed = result.diagnostics.features_computed;
  timing->features_cached = result.diagnostics.features_cached;
  timing->pairs_cached = result.diagnostics.pairs_cached;
  timing->pairs_computed = result.diagnostics.candidate_pairs - result.diagnostics.pairs_cached;
  timing->vote_rows_computed = result.diagnostics.vote_rows_computed;
  timing->earlier_pairs = result.diagnostics.earlier_pairs;
  // "projective (its matches, covariance, time)", "icp (projective: why it was not used)" or "icp".
  timing->refinement = result.diagnostics.projective_refinement ? "projective" : "icp";
  if (!result.diagnostics.projective_note.empty()) {
    timing->refinement += std::string(result.diagnostics.projective_refinement ? " (" : " (projective: ") +
                          result.diagnostics.projective_note + ")";
  }
  timing->projective_ms = result.diagnostics.ms_projective;
  // The pipeline cached the features of the snapshot's keyframes; those that left the map
  // while it ran were invalidated before they were stored: forget them now, or the cache
  // grows with every merge of a streaming agent (the soak test's resident memory).
  for (const Snapshot* snapshot : {&s, &t}) {
    std::lock_guard<std::mutex> lock(snapshot->agent->mutex);
    const std::vector<long> now = snapshot->agent->store.keyframeIds();
    std::vector<long> left;
    for (long id : snapshot->store.keyframeIds()) {
      if (std::find(now.begin(), now.end(), id) == now.end()) left.push_back(id);
    }
    forgetFeatures(*snapshot->agent, 0, false, left);
  }
  const RegistrationReport& r = result.report;
  Response response = answer(statusCode(r.status), statusName(r.status), r.message);
  if (r.status == Status::kOk && r.transform && r.covariance) {
    const Clock::time_point published = Clock::now();
    publishMerge(job, s, source_map, t, target_map, r, r.message, &response.edge);
    if (!options_.g2o_file.empty()) writePoseGraph(job, source_map, target_map, result);
    timing->publish_ms = msSince(published);
  } else if (r.status == Status::kOk) {
    response = answer(Response::INVALID_INPUT, "INVALID_INPUT", "the pipeline said OK without an edge: " + r.message);
  }
  return response;
}

void MergeNode::publishMerge(const MergeJob& job, const Snapshot& source, const AgentMap& source_map,
                             const Snapshot& target, const AgentMap& target_map, const RegistrationReport& report,
                             const std::string& message, pcr_pro::MapEdge* edge) {
  const ros::Time stamp = ros::Time::now();
  const EdgeNames names{job.source, job.target, source.agent->options.frame_id, target.agent->options.frame_id};
  *edge = edgeToMsg(report, names, stamp);
  edge_pub_.publish(*edge);
  geometry_msgs::PoseWithCovarianceStamped edge_pose;
  edge_pose.header = edge->header;
  edge_pose.pose = edge->pose;
  edge_pose_pub_.publish(edge_pose);
  const Sim3& s = *report.transform;
  Cloud fused(3, target_map.cloud.cols() + source_map.cloud.cols());
  fused << target_map.cloud, s.apply(source_map.cloud);
  // The source map in target units, in its own scaled frame (scaledFrame()): the rigid tf from the
  // target map puts it onto the target, and no frame claims coordinates it does not use.
  const std::string scaled = scaledFrame(names.source_frame);
  try {
    fused_pub_.publish(cloudToPclMsg(fused, names.target_frame, stamp));
    aligned_pub_.publish(cloudToPclMsg(source_map.cloud * s.scale(), scaled, stamp));
  } catch (const InputError& e) {
    // Coordinates beyond float range (a FLOAT64 map far from its origin, scaled up): the edge and
    // tf still go out; the clouds cannot be carried by a FLOAT32 PointCloud2.
    ROS_ERROR("merged %s into %s but cannot publish the clouds: %s", job.source.c_str(), job.target.c_str(), e.what());
  }
  if (options_.publish_tf) static_tf_.sendTransform(rigidTransformToMsg(s, names.target_frame, scaled, stamp));
  recordHistory(job, *edge, message);
  char fit[96] = "no ICP result";  // the keyframe estimate kept, or the projective refinement
  if (edge->correspondences > 0) {
    std::snprintf(fit, sizeof fit, "fitness %.4g, %d correspondences", edge->fitness_rmse, edge->correspondences);
  }
  ROS_INFO("merged %s into %s (%s): scale %.5g +- %.2g, t [%.4g %.4g %.4g], keyframes %ld -> %ld, %s",
           job.source.c_str(), job.target.c_str(), job.trigger.c_str(), s.scale(), edge->scale_stddev,
           s.translation().x(), s.translation().y(), s.translation().z(), static_cast<long>(edge->source_keyframe),
           static_cast<long>(edge->target_keyframe), fit);
}

void MergeNode::writePoseGraph(const MergeJob& job, const AgentMap& source_map, const AgentMap& target_map,
                               const MergeResult& result) const {
  const std::optional<MergeEdge> edge = poseGraphEdge(result);
  if (!edge) return;
  try {
    writeTextFileAtomically(options_.g2o_file,
                            toG2o(mergePoseGraph(target_map, job.target, source_map, job.source, *edge)));
  } catch (const InputError& e) {
    ROS_WARN("~g2o_file: the pose graph of %s -> %s was not written: %s", job.source.c_str(), job.target.c_str(),
             e.what());
  }
}

void MergeNode::recordHistory(const MergeJob& job, const pcr_pro::MapEdge& edge, const std::string& message) {
  pcr_pro::MergeRecord record;
  record.stamp = edge.header.stamp;
  record.trigger = job.trigger;
  record.status = Response::OK;
  record.status_name = "OK";
  record.message = message;
  record.edge = edge;
  pcr_pro::EdgeHistory history;
  {
    std::lock_guard<std::mutex> lock(history_mutex_);
    history_.push_back(record);
    const auto same_pair = [&](const pcr_pro::MergeRecord& r) {
      return r.edge.source_agent == edge.source_agent && r.edge.target_agent == edge.target_agent;
    };
    if (std::count_if(history_.begin(), history_.end(), same_pair) > options_.max_history_per_pair) {
      history_.erase(std::find_if(history_.begin(), history_.end(), same_pair));
      ROS_WARN_THROTTLE(60.0, "merge history: more than max_history_per_pair = %d edges %s -> %s: dropped the oldest",
                        options_.max_history_per_pair, edge.source_agent.c_str(), edge.target_agent.c_str());
    }
    history.records = history_;
  }
  history.header.stamp = edge.header.stamp;
  history_pub_.publish(history);
}

void MergeNode::noteOutcome(const MergeJob& job, const Response& response, const std::optional<MergeTiming>& timing) {
  if (response.status != Response::OK) {
    ROS_INFO("merge %s -> %s (%s): %s: %s%s", job.source.c_str(), job.target.c_str(), job.trigger.c_str(),
             response.status_name.c_str(), response.message.c_str(),
             job.trigger == "auto" ? "; the last good edge stays published" : "");
  }
  std::lock_guard<std::mutex> lock(merge_state_mutex_);
  merge_state_.attempted = true;
  merge_state_.status = response.status_name;
  merge_state_.message = response.message;
  merge_state_.pair = job.source + " -> " + job.target;
  merge_state_.trigger = job.trigger;
  (response.status == Response::OK ? merge_state_.merges_ok : merge_state_.merges_failed)++;
  if (job.trigger == "auto") ++merge_state_.merges_auto;
  if (timing) merge_state_.timing = timing;
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
  s.add("last_pair", merge_state_.pair);
  s.add("last_trigger", merge_state_.trigger);
  s.add("merges_ok", merge_state_.merges_ok);
  s.add("merges_failed", merge_state_.merges_failed);
  s.add("merges_auto", merge_state_.merges_auto);
  s.add("auto_merge", options_.auto_merge.enabled ? "into " + options_.autoMergeTarget() : std::string("off"));
  if (const std::optional<MergeTiming>& t = merge_state_.timing) {
    // Where the last merge that ran the pipeline spent its wall time on the worker [ms].
    char stages[240];
    std::snprintf(stages, sizeof(stages), "features %.0f, relative_pose %.0f, scale %.0f, filters %.0f, icp %.0f, "
                  "covariance %.0f, arbitration %.0f", t->stages.features, t->stages.relative_pose, t->stages.scale,
                  t->stages.filters, t->stages.icp, t->stages.covariance, t->stages.arbitration);
    s.addf("last_merge_ms", "%.1f", t->total_ms);
    s.addf("last_maps_ms", "%.1f", t->maps_ms);
    s.addf("last_pipeline_ms", "%.1f", t->stages.total);
    s.add("last_stages_ms", stages);
    s.addf("last_publish_ms", "%.1f", t->publish_ms);
    s.add("last_features_computed", t->features_computed);
    s.add("last_features_cached", t->features_cached);
    s.add("last_pairs_computed", t->pairs_computed);
    s.add("last_pairs_cached", t->pairs_cached);
    s.add("last_vote_rows_computed", t->vote_rows_computed);
    s.add("last_earlier_pairs", t->earlier_pairs);
    s.add("last_refinement", t->refinement);
    s.addf("last_projective_ms", "%.1f", t->projective_ms);
  }
  std::lock_guard<std::mutex> history_lock(history_mutex_);
  s.add("history_edges", history_.size());
}

}  // namespace ros_bridge
}  // namespace pcr_pro
