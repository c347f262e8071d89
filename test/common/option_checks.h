// The stages' option tests: each option set out of its range must be refused by validate() with
// an InputError naming the option (one table per stage instead of a copy-edit-check block a key).
#pragma once

#include <gtest/gtest.h>

#include <functional>
#include <string>
#include <vector>

#include "pcr_pro/geometry/types.h"

namespace pcr_pro {
namespace test {

/// One option of O set to a value its range refuses, and what the refusal must name.
template <typename O>
struct BadOption {
  std::function<void(O*)> set;  ///< applied to default options
  std::string key;              ///< e.g. "matching.image_scale"
};

/// @return the message of validate(o), "" when it passes
template <typename O>
std::string validateMessage(const O& o) {
  try {
    validate(o);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

/// Expects the defaults to pass validate() and every bad option applied to them to be refused
/// naming its key; also(o), when given, then runs on each bad option set (e.g. the stage's own
/// functions, which validate too).
template <typename O>
void expectEachRefused(const std::vector<BadOption<O>>& cases, const std::function<void(const O&)>& also = {}) {
  EXPECT_EQ(validateMessage(O()), "");
  for (const BadOption<O>& c : cases) {
    O o;
    c.set(&o);
    const std::string message = validateMessage(o);
    EXPECT_NE(message, "") << "no error for " << c.key;
    EXPECT_NE(message.find(c.key), std::string::npos) << message;
    if (also) also(o);
  }
}

}  // namespace test
}  // namespace pcr_pro
