// The system BLAS's thread count, fixed for the duration of a solve. OpenBLAS takes its count from the
// environment (a Ray worker sets OMP_NUM_THREADS=1) or the machine, and its Cholesky blocks by it: CHOLMOD's
// factorisation, hence the last digits of a solve's result, would then differ between a process and a Ray worker
// running the same video. With a BLAS other than OpenBLAS this does nothing.
#pragma once

#include <dlfcn.h>

namespace m3c::util {

class ScopedBlasThreads {
 public:
  explicit ScopedBlasThreads(int num_threads) {
    using Get = int (*)();
    void* lib = dlopen("libopenblas.so.0", RTLD_LAZY | RTLD_NOLOAD);  // only if the process already uses it
    if (lib == nullptr) return;
    set_ = reinterpret_cast<Set>(dlsym(lib, "openblas_set_num_threads"));
    const auto get = reinterpret_cast<Get>(dlsym(lib, "openblas_get_num_threads"));
    dlclose(lib);  // still loaded: it was before
    if (set_ == nullptr || get == nullptr) {
      set_ = nullptr;
      return;
    }
    previous_ = get();
    set_(num_threads < 1 ? 1 : num_threads);
  }
  ~ScopedBlasThreads() {
    if (set_ != nullptr) set_(previous_);
  }
  ScopedBlasThreads(const ScopedBlasThreads&) = delete;
  ScopedBlasThreads& operator=(const ScopedBlasThreads&) = delete;

 private:
  using Set = void (*)(int);
  Set set_ = nullptr;
  int previous_ = 1;
};

}  // namespace m3c::util
