// Checks that throw instead of aborting: code reached from Python must never take the process down.
// std::invalid_argument becomes ValueError in Python (pybind11's default translation).
#pragma once

#include <sstream>
#include <stdexcept>
#include <string>

namespace m3c {

namespace internal {
class CheckMessage {
 public:
  CheckMessage(const char* file, int line, const char* condition) {
    stream_ << condition << " failed (" << file << ":" << line << ")";
  }
  template <typename T>
  CheckMessage& operator<<(const T& value) {
    if (!has_detail_) {
      stream_ << ": ";
      has_detail_ = true;
    }
    stream_ << value;
    return *this;
  }
  [[noreturn]] void Throw() const { throw std::invalid_argument(stream_.str()); }

 private:
  std::ostringstream stream_;
  bool has_detail_ = false;
};

// Lets `M3C_CHECK(c) << "detail";` throw at the end of the full expression.
struct CheckThrower {
  [[noreturn]] void operator&(const CheckMessage& message) const { message.Throw(); }
};
}  // namespace internal

}  // namespace m3c

#define M3C_CHECK(condition) \
  (condition) ? (void)0      \
              : ::m3c::internal::CheckThrower() & ::m3c::internal::CheckMessage(__FILE__, __LINE__, #condition)

#define M3C_CHECK_EQ(a, b) M3C_CHECK((a) == (b)) << #a " = " << (a) << ", " #b " = " << (b) << " "
