#include "pcr_pro/geometry/types.h"

#include <array>
#include <utility>

namespace pcr_pro {
namespace {
constexpr std::array<std::pair<Status, const char*>, 9> kStatusNames{{
    {Status::kOk, "OK"},
    {Status::kNotEnoughMatches, "NOT_ENOUGH_MATCHES"},
    {Status::kRelativePoseFailed, "RELATIVE_POSE_FAILED"},
    {Status::kScaleFailed, "SCALE_FAILED"},
    {Status::kIcpNotConverged, "ICP_NOT_CONVERGED"},
    {Status::kDegenerate, "DEGENERATE"},
    {Status::kInvalidInput, "INVALID_INPUT"},
    {Status::kNoOverlap, "NO_OVERLAP"},
    {Status::kInconsistent, "INCONSISTENT"},
}};
}  // namespace

const char* statusName(Status status) {
  for (const auto& entry : kStatusNames) {
    if (entry.first == status) return entry.second;
  }
  return "UNKNOWN";
}

bool parseStatus(const std::string& name, Status* status) {
  for (const auto& entry : kStatusNames) {
    if (name == entry.second) {
      *status = entry.first;
      return true;
    }
  }
  return false;
}

}  // namespace pcr_pro
