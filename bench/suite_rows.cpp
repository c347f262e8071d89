#include <cstdio>

#include "pcr_pro/io/text_escape.h"
#include "suite.h"

namespace pcr_pro {
namespace bench {

std::string fmt(double v, int prec) {
  char b[64];
  std::snprintf(b, sizeof b, "%.*f", prec, v);
  return b;
}

std::string pct(int num, int den) { return den ? fmt(100.0 * num / den, 0) + " %" : "n/a"; }

Row fromReport(const RegistrationReport& rep, const Sim3& truth, double extent, double ms) {
  Row r;
  r.status = statusName(rep.status);
  r.ms = ms;
  if (rep.transform) {
    r.err = errors(*rep.transform, truth);
    r.ok = rep.status == Status::kOk && success(r.err, extent);
  } else {
    r.err = Errors{180.0, 1e9, 1e9};
  }
  return r;
}

Row fromPeer(const PeerResult& p, const Sim3& truth, double extent) {
  Row r;
  r.ms = p.ms;
  r.status = p.ran ? "RAN" : "FAILED";
  if (p.ran) {
    r.err = errors(p.transform, truth);
    r.ok = success(r.err, extent);
  } else {
    r.err = Errors{180.0, 1e9, 1e9};
  }
  return r;
}

void writeRows(std::FILE* f, const std::vector<Row>& rows) {
  std::fprintf(f, "method,variant,ratio,roll_deg,sparsity,status,rotation_deg,translation,scale_rel,success,ms\n");
  for (const Row& r : rows) {
    std::fprintf(f, "%s,%s,%g,%g,%g,%s,%.6g,%.6g,%.6g,%d,%.2f\n", csvField(r.method).c_str(),
                 csvField(r.variant).c_str(), r.ratio, r.roll, r.sparsity, csvField(r.status).c_str(),
                 r.err.rotation_deg, r.err.translation, r.err.scale_rel, r.ok ? 1 : 0, r.ms);
  }
}

}  // namespace bench
}  // namespace pcr_pro
