// OpenMP parallelism of the calling thread, set for a scope. Why: CHOLMOD's supernodal factorization
// (SuiteSparse 5) opens a team of CHOLMOD_OMP_NUM_THREADS = 4 OpenMP threads, a compile-time constant, for each
// large supernode, thousands of times per factorization: on a 2-core machine beside Ceres's own threads its
// teams cost a quarter of the world optimizer's linear solver in wake-ups and spinning (bench/motion_optimizer.py).
// Those loops only scatter and zero values, so serialising them leaves every result unchanged. The limit is
// OpenMP's max-active-levels, an ICV of the calling thread's data environment (OpenMP 5.0; libgomp since GCC 11):
// other threads keep theirs. Without OpenMP this does nothing.
#pragma once

#ifdef _OPENMP
#include <omp.h>
#endif

namespace m3c::util {

class ScopedOpenMpLevels {
 public:
  // levels: nested parallel regions allowed on this thread; 0 runs every parallel region on one thread.
  explicit ScopedOpenMpLevels(int levels) {
#ifdef _OPENMP
    previous_ = omp_get_max_active_levels();
    omp_set_max_active_levels(levels);
#else
    (void)levels;
#endif
  }
  ~ScopedOpenMpLevels() {
#ifdef _OPENMP
    omp_set_max_active_levels(previous_);
#endif
  }
  // This thread's limit now (1 when OpenMP is off: a loop runs as written).
  static int Current() {
#ifdef _OPENMP
    return omp_get_max_active_levels();
#else
    return 1;
#endif
  }
  ScopedOpenMpLevels(const ScopedOpenMpLevels&) = delete;
  ScopedOpenMpLevels& operator=(const ScopedOpenMpLevels&) = delete;

 private:
  int previous_ = 1;
};

}  // namespace m3c::util
