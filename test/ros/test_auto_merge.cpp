// When the merge node merges on its own (AutoMergeSchedule) and the validation of the node's new
// options (issue 14): gtest, no ROS master.
#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <fstream>
#include <functional>
#include <set>
#include <sstream>

#include "common/option_checks.h"
#include "pcr_pro/merge/parameter_tables.h"
#include "pcr_pro/ros/auto_merge.h"
#include "pcr_pro/ros/node_options.h"

namespace pcr_pro {
namespace ros_bridge {
namespace {

MapProgress progress(std::size_t keyframes, std::uint64_t added, std::uint64_t moved = 0, bool cloud = true) {
  MapProgress p;
  p.keyframes = keyframes;
  p.added = added;
  p.moved = moved;
  p.has_cloud = cloud;
  return p;
}

AutoMergeOptions options(int min_keyframes, int new_keyframes, bool after_graph_update = true) {
  AutoMergeOptions o;
  o.enabled = true;
  o.min_keyframes = min_keyframes;
  o.new_keyframes = new_keyframes;
  o.after_graph_update = after_graph_update;
  return o;
}

TEST(AutoMergeSchedule, FirstMergeOnceBothMapsHaveEnoughKeyframesAndACloud) {
  AutoMergeSchedule s(options(3, 5), "a", {"b"});
  EXPECT_TRUE(s.due({{"a", progress(3, 3)}, {"b", progress(2, 2)}}).source.empty());
  EXPECT_TRUE(s.due({{"a", progress(3, 3)}, {"b", progress(3, 3, 0, false)}}).source.empty()) << "no cloud yet";
  EXPECT_TRUE(s.due({{"b", progress(3, 3)}}).source.empty()) << "target unknown";
  const DueMerge due = s.due({{"a", progress(3, 3)}, {"b", progress(3, 3)}});
  EXPECT_EQ(due.source, "b");
  EXPECT_EQ(due.reason, "first merge");
}

TEST(AutoMergeSchedule, AgainAfterGrowthOrMovedKeyframesNotBefore) {
  AutoMergeSchedule s(options(2, 4), "a", {"b"});
  s.attempted("b", progress(2, 2), progress(3, 3));
  EXPECT_TRUE(s.due({{"a", progress(3, 3)}, {"b", progress(2, 2)}}).source.empty()) << "nothing changed";
  // Growth counts new ids in both maps together (the keyframe cap may keep the counts flat).
  EXPECT_TRUE(s.due({{"a", progress(3, 5)}, {"b", progress(2, 3)}}).source.empty()) << "3 new < 4";
  DueMerge due = s.due({{"a", progress(3, 6)}, {"b", progress(2, 3)}});
  EXPECT_EQ(due.source, "b");
  EXPECT_EQ(due.reason, "4 new keyframes");
  // A graph update or a re-sent keyframe of either map.
  due = s.due({{"a", progress(3, 3, 1)}, {"b", progress(2, 2)}});
  EXPECT_EQ(due.reason, "keyframes moved");
  // ... unless disabled.
  AutoMergeSchedule quiet(options(2, 4, false), "a", {"b"});
  quiet.attempted("b", progress(2, 2), progress(3, 3));
  EXPECT_TRUE(quiet.due({{"a", progress(3, 3, 5)}, {"b", progress(2, 2, 5)}}).source.empty());
  // A failed attempt counts as an attempt: no retry until the maps change.
  s.attempted("b", progress(2, 3), progress(3, 6));
  EXPECT_TRUE(s.due({{"a", progress(3, 6)}, {"b", progress(2, 3)}}).source.empty());
}

TEST(AutoMergeSchedule, PairsTakeTurns) {
  AutoMergeSchedule s(options(1, 1), "a", {"b", "c"});
  const std::map<std::string, MapProgress> all{{"a", progress(1, 1)}, {"b", progress(1, 1)}, {"c", progress(1, 1)}};
  EXPECT_EQ(s.due(all).source, "b");
  EXPECT_EQ(s.due(all).source, "c");  // b is still due (never attempted), but c's turn comes first
  s.attempted("b", progress(1, 1), progress(1, 1));
  s.attempted("c", progress(1, 1), progress(1, 1));
  EXPECT_TRUE(s.due(all).source.empty());
}

TEST(AutoMergeOptions, RangesAreEnforced) {
  std::vector<test::BadOption<AutoMergeOptions>> bad{
      {[](AutoMergeOptions* o) { o->min_keyframes = 0; }, "auto_merge/min_keyframes"},
      {[](AutoMergeOptions* o) { o->new_keyframes = 0; }, "auto_merge/new_keyframes"},
  };
  for (const double period : {0.0, -1.0, 0.001, 61.0}) {
    bad.push_back({[period](AutoMergeOptions* o) { o->period = period; }, "auto_merge/period"});
  }
  test::expectEachRefused(bad);
}

TEST(NodeOptions, NewRangesAreEnforcedNamingTheKey) {
  const auto refused = [](const std::function<void(NodeOptions&)>& change, const std::string& key) {
    NodeOptions o;
    change(o);
    const std::string message = test::validateMessage(o);
    EXPECT_NE(message.find("~" + key), std::string::npos) << key << ": '" << message << "'";
  };
  EXPECT_NO_THROW(validate(NodeOptions()));
  for (const double period : {0.0, -1.0, 0.001, 61.0}) {
    refused([&](NodeOptions& o) { o.diagnostic_period = period; }, "diagnostic_period");
  }
  refused([](NodeOptions& o) { o.seed = -1; }, "seed");
  refused([](NodeOptions& o) { o.seed = 2147483648LL; }, "seed");
  refused([](NodeOptions& o) { o.max_history_per_pair = 0; }, "max_history_per_pair");
  refused([](NodeOptions& o) { o.g2o_file = "/nonexistent_pcr_pro_dir/graph.g2o"; }, "g2o_file");
  refused([](NodeOptions& o) { o.g2o_file = "/tmp"; }, "g2o_file");
  EXPECT_NO_THROW(validate([] {
    NodeOptions o;
    o.g2o_file = "/tmp/pcr_pro_graph.g2o";
    return o;
  }()));
  refused([](NodeOptions& o) { o.auto_merge.target = "agent_x"; }, "auto_merge/target");
  refused([](NodeOptions& o) { o.auto_merge.period = 0.0; }, "auto_merge/period");
  // The schemas' range messages keep the node's shape: key, range, value.
  refused([](NodeOptions& o) { o.queue_size = 0; }, "queue_size: must be >= 1, got 0");
  refused([](NodeOptions& o) { o.lsd.min_near_support = 10; }, "lsd.min_near_support: must be in [0, 9], got 10");
  refused([](NodeOptions& o) { o.limits.max_cloud_points = 999; },
          "max_cloud_points_per_agent: must be in [1000, 200000000], got 999");
  refused([](NodeOptions& o) { o.agents[1].frame_id = "agent_a/map_scaled"; }, "agent_b/frame_id");
  NodeOptions d;
  EXPECT_EQ(d.autoMergeTarget(), "agent_a");
  d.auto_merge.target = "agent_b";
  EXPECT_EQ(d.autoMergeTarget(), "agent_b");
  EXPECT_EQ(scaledFrame("agent_b/map"), "agent_b/map_scaled");
}

TEST(NodeParameters, ReadmeTableIsTheSchemaTable) {
  // The README's node parameters are printed from the schemas (pcr_pro_params --update README.md).
  std::ifstream in(PCR_PRO_README);
  std::stringstream readme;
  readme << in.rdbuf();
  const std::string table = nodeParameterTable();
  EXPECT_NE(table.find("| `auto_merge/period` | double | `1` | in [0.05, 60] | s |"), std::string::npos) << table;
  EXPECT_NE(readme.str().find("<!-- params:node -->\n" + table + "<!-- /params:node -->"), std::string::npos)
      << "README.md: the node's parameter table differs from the schema: run pcr_pro_params --update README.md";
}

TEST(NodeParameters, ShippedFileStatesEveryParameterWithItsDefault) {
  // config/merge_node.yaml documents every parameter with its default, but the two files that
  // launch/merge_node.launch sets from its arguments.
  const std::set<std::string> set_by_the_launch{"merge_config", "icp_config"};
  const YAML::Node file = YAML::LoadFile(PCR_PRO_NODE_YAML);
  std::vector<ParamRow> rows = paramRows(paramSchema<NodeOptions>(), '/');
  for (const auto& more : {paramRows(paramSchema<StoreLimits>(), '/'), paramRows(paramSchema<LsdFilterOptions>(), '/'),
                           paramRows(paramSchema<AutoMergeOptions>(), '/')}) {
    rows.insert(rows.end(), more.begin(), more.end());
  }
  ASSERT_GT(rows.size(), 15u);
  for (const ParamRow& row : rows) {
    YAML::Node node = file;  // reset(), not =: assigning a YAML::Node writes into the tree
    std::string rest = row.key;
    for (std::size_t slash; node.IsMap() && (slash = rest.find('/')) != std::string::npos; rest = rest.substr(slash + 1)) {
      node.reset(node[rest.substr(0, slash)]);
    }
    const bool stated = node.IsMap() && node[rest];
    EXPECT_EQ(stated, set_by_the_launch.count(row.key) == 0) << row.key;
    if (!stated) continue;
    const std::string value = node[rest].Scalar();
    if (row.type == "double") {
      EXPECT_EQ(std::stod(value), std::stod(row.default_value)) << row.key;
    } else {
      EXPECT_EQ(value.empty() ? "\"\"" : value, row.default_value) << row.key;
    }
  }
  ASSERT_TRUE(file["agents"].IsSequence());
  EXPECT_EQ(file["agents"].as<std::vector<std::string>>(), (std::vector<std::string>{"agent_a", "agent_b"}));
}

}  // namespace
}  // namespace ros_bridge
}  // namespace pcr_pro
