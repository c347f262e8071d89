// Shared by the ROS message fuzz targets (fuzz_ros_*, fuzz_lsd_*): the input is one message in ROS
// serialization, exactly the bytes a subscriber deserializes.
//
// roscpp's deserializer resizes a vector to the length prefix it reads before it checks that the
// bytes are there, so a 4-byte prefix can demand gigabytes. That is roscpp's behaviour (the same
// in a running node, where the transport caps a message at its declared size, which the
// publisher chooses), not what these targets test: inputs whose length prefixes exceed the input
// are skipped. A first pass deserializes into the message type instantiated with an allocator
// that refuses any allocation of more elements than the input has bytes; only when that passes
// is the message deserialized into the ordinary type and handed to our conversion.
#pragma once

#include <ros/serialization.h>

#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <memory>
#include <new>
#include <string>

#include "fuzz_common.h"

namespace pcr_pro {
namespace fuzz {

/// Thrown by BoundedAllocator (deliberately not a std::exception, so nothing else catches it).
struct LengthBeyondInput {};

inline std::size_t& elementBudget() {
  static thread_local std::size_t budget = 0;
  return budget;
}

/// std::allocator that refuses more than elementBudget() elements in one allocation.
template <class T>
struct BoundedAllocator {
  using value_type = T;
  template <class U>
  struct rebind {
    using other = BoundedAllocator<U>;
  };
  BoundedAllocator() noexcept = default;
  template <class U>
  BoundedAllocator(const BoundedAllocator<U>&) noexcept {}  // NOLINT: implicit, as allocators are
  T* allocate(std::size_t n) {
    if (n > elementBudget()) throw LengthBeyondInput();
    return static_cast<T*>(::operator new(n * sizeof(T)));
  }
  void deallocate(T* p, std::size_t) noexcept { ::operator delete(p); }
};
template <class T, class U>
bool operator==(const BoundedAllocator<T>&, const BoundedAllocator<U>&) noexcept {
  return true;
}
template <class T, class U>
bool operator!=(const BoundedAllocator<T>&, const BoundedAllocator<U>&) noexcept {
  return false;
}

/**
 * Deserializes `data` into `out` (a message type M_<std::allocator<void>>).
 * @return false when the bytes are not a message of this type (too short, or a length prefix
 * beyond the input): not a finding, the input is skipped.
 */
template <template <class> class M>
bool deserializeMessage(const std::uint8_t* data, std::size_t size, M<std::allocator<void>>* out) {
  namespace ser = ros::serialization;
  if (size > 0xFFFFFFFFu) return false;
  auto* bytes = const_cast<std::uint8_t*>(data);  // IStream does not write
  try {
    M<BoundedAllocator<void>> probe;
    elementBudget() = size + 1;  // a string allocates its length + 1
    ser::IStream stream(bytes, static_cast<std::uint32_t>(size));
    ser::deserialize(stream, probe);
  } catch (const LengthBeyondInput&) {
    return false;
  } catch (const ser::StreamOverrunException&) {
    return false;
  }
  // Every length prefix fits in the input: the ordinary deserialization allocates at most that much.
  ser::IStream stream(bytes, static_cast<std::uint32_t>(size));
  ser::deserialize(stream, *out);
  return true;
}

/// An InputError of a message conversion: one line, "<field>: <what>", the field one of `fields`
/// (a prefix: "frameData" also matches "frameData[3] (keyframe 7): ...").
inline void requireFieldError(const std::string& message, std::initializer_list<const char*> fields) {
  require(message.find('\n') == std::string::npos, "error message is not one line", message);
  require(message.find(": ") != std::string::npos, "error message does not say '<field>: <what>'", message);
  bool named = false;
  for (const char* f : fields) named = named || message.rfind(f, 0) == 0;
  require(named, "error message does not start with the message field at fault", message);
}

}  // namespace fuzz
}  // namespace pcr_pro
