#include "util/openmp_levels.h"

#include <gtest/gtest.h>

#include <thread>

namespace m3c::util {
namespace {

#ifdef _OPENMP
int TeamSize(int requested) {
  int size = 0;
#pragma omp parallel num_threads(requested)
  {
#pragma omp single
    size = omp_get_num_threads();
  }
  return size;
}

TEST(ScopedOpenMpLevels, SerialisesThisThreadOnlyAndRestores) {
  ASSERT_GE(ScopedOpenMpLevels::Current(), 1);
  EXPECT_EQ(TeamSize(3), 3);  // an explicit num_threads, as CHOLMOD's teams have
  {
    const ScopedOpenMpLevels serial(0);
    EXPECT_EQ(ScopedOpenMpLevels::Current(), 0);
    EXPECT_EQ(TeamSize(3), 1);
    int other = 0;  // another thread keeps its own limit
    std::thread t([&] { other = TeamSize(3); });
    t.join();
    EXPECT_EQ(other, 3);
    {
      const ScopedOpenMpLevels ours(1);  // an evaluation callback inside the solve
      EXPECT_EQ(TeamSize(3), 3);
    }
    EXPECT_EQ(TeamSize(3), 1);
  }
  EXPECT_EQ(TeamSize(3), 3);
}
#else
TEST(ScopedOpenMpLevels, DoesNothingWithoutOpenMp) {
  const ScopedOpenMpLevels serial(0);
  EXPECT_EQ(ScopedOpenMpLevels::Current(), 1);
}
#endif

}  // namespace
}  // namespace m3c::util
