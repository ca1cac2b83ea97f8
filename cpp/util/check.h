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
  CheckMessage(const char* file, int line, const char* condition) : file_(file), line_(line), condition_(condition) {}
  template <typename T>
  CheckMessage& operator<<(const T& value) {
    detail_ << value;
    return *this;
  }
  // The detail (written for people) first, the failed condition and its place after it, for developers.
  [[noreturn]] void Throw() const {
    const std::string file(file_);
    const std::string where = file.substr(file.find_last_of('/') + 1) + ":" + std::to_string(line_);
    const std::string detail = detail_.str();
    if (detail.empty()) throw std::invalid_argument(std::string(condition_) + " failed (" + where + ")");
    throw std::invalid_argument(detail + " [check " + condition_ + " at " + where + "]");
  }

 private:
  const char* file_;
  int line_;
  const char* condition_;
  std::ostringstream detail_;
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
