// sensor_msgs/PointCloud2 <-> core clouds (see msg_conversion.h).
#include "pcr_pro/ros/msg_conversion.h"

#include <pcl_conversions/pcl_conversions.h>

#include <cstring>

#include "msg_checks.h"
#include "pcr_pro/pcl.h"

namespace pcr_pro {
namespace ros_bridge {

using namespace detail;

Cloud cloudFromMsg(const sensor_msgs::PointCloud2& msg) {
  // width * height * point_step can exceed 64 bits (3 x 32 bits): compare without overflow.
  const std::uint64_t points = static_cast<std::uint64_t>(msg.width) * msg.height;
  const bool fits = msg.point_step == 0 || points <= msg.data.size() / msg.point_step;
  const std::uint64_t expected = fits ? points * msg.point_step : 0;
  if (!fits || expected != msg.data.size()) {
    fail("cloud", "width * height * point_step = " + str(msg.width) + " * " + str(msg.height) + " * " +
                      str(msg.point_step) + (fits ? " = " + str(expected) : std::string()) + " != data size " +
                      str(msg.data.size()));
  }
  if (msg.height > 0 && static_cast<std::uint64_t>(msg.row_step) != static_cast<std::uint64_t>(msg.width) * msg.point_step) {
    fail("cloud", "row_step " + str(msg.row_step) + " != width * point_step " +
                      str(static_cast<std::uint64_t>(msg.width) * msg.point_step));
  }
  if (msg.is_bigendian) fail("cloud", "big-endian data is not supported");
  int offsets[3] = {-1, -1, -1};
  bool is_double[3] = {false, false, false};
  const char* names[3] = {"x", "y", "z"};
  for (std::size_t i = 0; i < msg.fields.size(); ++i) {
    const sensor_msgs::PointField& f = msg.fields[i];
    for (int k = 0; k < 3; ++k) {
      if (f.name != names[k]) continue;
      const std::string field = std::string("field ") + names[k] + " (fields[" + str(i) + "])";
      // Two fields of one name: which one holds is undefined (a reader taking the last, another
      // the first), so the cloud is refused rather than read either way.
      if (offsets[k] >= 0) fail("cloud", field + " is a duplicate: '" + names[k] + "' appears twice");
      if (f.count != 1) fail("cloud", field + " has count " + str(f.count) + ": a coordinate must have count 1");
      if (f.datatype != sensor_msgs::PointField::FLOAT32 && f.datatype != sensor_msgs::PointField::FLOAT64) {
        fail("cloud", std::string("field ") + names[k] + " must be FLOAT32 or FLOAT64, got datatype " +
                          str(static_cast<int>(f.datatype)));
      }
      is_double[k] = f.datatype == sensor_msgs::PointField::FLOAT64;
      if (static_cast<std::uint64_t>(f.offset) + (is_double[k] ? 8 : 4) > msg.point_step) {
        fail("cloud", std::string("field ") + names[k] + " at offset " + str(f.offset) + " lies outside point_step " +
                          str(msg.point_step));
      }
      offsets[k] = static_cast<int>(f.offset);
    }
  }
  for (int k = 0; k < 3; ++k) {
    if (offsets[k] < 0) fail("cloud", std::string("no field '") + names[k] + "'");
  }
  const std::size_t n = static_cast<std::size_t>(msg.width) * msg.height;
  Cloud cloud(3, static_cast<Eigen::Index>(n));
  Eigen::Index kept = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const std::uint8_t* p = &msg.data[i * msg.point_step];
    Eigen::Vector3d v;
    for (int k = 0; k < 3; ++k) {
      if (is_double[k]) {
        double d;
        std::memcpy(&d, p + offsets[k], 8);
        v[k] = d;
      } else {
        float f;
        std::memcpy(&f, p + offsets[k], 4);
        v[k] = f;
      }
    }
    if (v.allFinite()) cloud.col(kept++) = v;
  }
  cloud.conservativeResize(3, kept);
  return cloud;
}

sensor_msgs::PointCloud2 cloudToMsg(const Cloud& cloud, const std::string& frame_id, const ros::Time& stamp) {
  sensor_msgs::PointCloud2 msg;
  msg.header.frame_id = frame_id;
  msg.header.stamp = stamp;
  msg.height = 1;
  msg.width = static_cast<std::uint32_t>(cloud.cols());
  const char* names[3] = {"x", "y", "z"};
  for (int k = 0; k < 3; ++k) {
    sensor_msgs::PointField f;
    f.name = names[k];
    f.offset = static_cast<std::uint32_t>(4 * k);
    f.datatype = sensor_msgs::PointField::FLOAT32;
    f.count = 1;
    msg.fields.push_back(f);
  }
  msg.is_bigendian = false;
  msg.point_step = 12;
  msg.row_step = msg.point_step * msg.width;
  msg.is_dense = true;
  msg.data.resize(static_cast<std::size_t>(msg.row_step));
  for (Eigen::Index i = 0; i < cloud.cols(); ++i) {
    const float xyz[3] = {static_cast<float>(cloud(0, i)), static_cast<float>(cloud(1, i)),
                          static_cast<float>(cloud(2, i))};
    std::memcpy(&msg.data[static_cast<std::size_t>(i) * 12], xyz, 12);
  }
  return msg;
}

sensor_msgs::PointCloud2 cloudToPclMsg(const Cloud& cloud, const std::string& frame_id, const ros::Time& stamp) {
  sensor_msgs::PointCloud2 msg;
  pcl::toROSMsg(*toPcl<pcl::PointXYZ>(cloud), msg);
  // pcl's header keeps microseconds only: the stamp is set here, exactly.
  msg.header.frame_id = frame_id;
  msg.header.stamp = stamp;
  return msg;
}

}  // namespace ros_bridge
}  // namespace pcr_pro
