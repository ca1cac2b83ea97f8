#include "body/lbs.h"

#include <algorithm>

#include "body/posing.h"
#include "util/check.h"

namespace m3c::body {

namespace {
// Frames per GEMM block: large enough for a fast pose-blend GEMM, small enough to keep (3V x chunk) in cache.
constexpr int kChunkFrames = 32;
}  // namespace

template <typename T>
void Forward(const BodyModel& model, int num_frames, const T* pose, const T* betas, bool betas_shared,
             const T* transl, T* vertices, T* joints) {
  M3C_CHECK(num_frames >= 0) << "num_frames must be >= 0";
  using Matrix = Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>;
  using Vector = Eigen::Matrix<T, Eigen::Dynamic, 1>;
  const auto& arrays = model.arrays<T>();
  const int V = model.num_vertices(), J = model.num_joints(), B = model.num_betas();
  const int P = 9 * (J - 1);

  // Shared shape: shape the mesh and the rest joints once.
  Vector v_shaped_shared;
  std::vector<T> rest_shared(3 * J);
  if (betas_shared) {
    Eigen::Map<const Vector> beta(betas, B);
    if (vertices) v_shaped_shared = arrays.v_template + arrays.shapedirs * beta;
    RestJoints(arrays, betas, rest_shared.data());
  }

  const auto& offsets = model.weight_offsets();
  const auto& weight_joints = model.weight_joints();
  const int chunk = std::min(kChunkFrames, std::max(num_frames, 1));
  Matrix features(P, chunk), posed(vertices ? 3 * V : 0, chunk), betas_block(B, chunk);
  std::vector<T> transforms(static_cast<size_t>(chunk) * J * 12);  // A_j = [Rw_j | o_j - Rw_j J_j], row-major

  for (int f0 = 0; f0 < num_frames; f0 += kChunkFrames) {
    const int n = std::min(kChunkFrames, num_frames - f0);
    // Kinematics per frame (cheap, serial).
    Skeleton<T> skeleton;
    skeleton.Resize(J);
    for (int i = 0; i < n; ++i) {
      const int f = f0 + i;
      if (betas_shared) {
        std::copy(rest_shared.begin(), rest_shared.end(), skeleton.rest_joints.begin());
      } else {
        RestJoints(arrays, betas + static_cast<size_t>(f) * B, skeleton.rest_joints.data());
      }
      PoseSkeleton(model.parents(), pose + static_cast<size_t>(f) * 3 * J, &skeleton);
      const T* t = transl ? transl + 3 * static_cast<size_t>(f) : nullptr;
      if (joints) {
        T* out = joints + static_cast<size_t>(f) * 3 * J;
        for (int k = 0; k < 3 * J; ++k) out[k] = skeleton.world_origin[k] + (t ? t[k % 3] : T(0));
      }
      if (!vertices) continue;
      PoseFeature(J, skeleton.local_rot.data(), features.col(i).data());
      if (!betas_shared) betas_block.col(i) = Eigen::Map<const Vector>(betas + static_cast<size_t>(f) * B, B);
      T* A = transforms.data() + static_cast<size_t>(i) * J * 12;
      for (int j = 0; j < J; ++j) {
        const T* R = skeleton.world_rot.data() + 9 * j;
        const T* o = skeleton.world_origin.data() + 3 * j;
        const T* Jj = skeleton.rest_joints.data() + 3 * j;
        T* Aj = A + 12 * j;
        for (int r = 0; r < 3; ++r) {
          Aj[4 * r] = R[3 * r];
          Aj[4 * r + 1] = R[3 * r + 1];
          Aj[4 * r + 2] = R[3 * r + 2];
          Aj[4 * r + 3] = o[r] - (R[3 * r] * Jj[0] + R[3 * r + 1] * Jj[1] + R[3 * r + 2] * Jj[2]);
        }
      }
    }
    if (!vertices) continue;

    // Blend shapes for the whole block. The product streams all of posedirs (memory-bound at small n), so
    // both cores take a band of rows each instead of relying on Eigen's single-threaded GEMV.
    const int rows = 3 * V;
    const int bands = 16;
#pragma omp parallel for schedule(static) if (rows > 3000)
    for (int band = 0; band < bands; ++band) {
      const int r0 = static_cast<int>(static_cast<long>(rows) * band / bands);
      const int r1 = static_cast<int>(static_cast<long>(rows) * (band + 1) / bands);
      auto out = posed.block(r0, 0, r1 - r0, n);
      out.noalias() = arrays.posedirs.middleRows(r0, r1 - r0) * features.leftCols(n);
      if (betas_shared) {
        out.colwise() += v_shaped_shared.segment(r0, r1 - r0);
      } else {
        out.noalias() += arrays.shapedirs.middleRows(r0, r1 - r0) * betas_block.leftCols(n);
        out.colwise() += arrays.v_template.segment(r0, r1 - r0);
      }
    }

    // Sparse skinning: each vertex blends only the joints that weigh on it.
    const T* wv = arrays.weight_values.data();
#pragma omp parallel for collapse(2) schedule(static) if (static_cast<long>(n) * V > 20000)
    for (int i = 0; i < n; ++i) {
      for (int v = 0; v < V; ++v) {
        const T* A = transforms.data() + static_cast<size_t>(i) * J * 12;
        T M[12] = {};
        for (int e = offsets[v]; e < offsets[v + 1]; ++e) {
          const T w = wv[e];
          const T* Aj = A + 12 * weight_joints[e];
          for (int c = 0; c < 12; ++c) M[c] += w * Aj[c];
        }
        const T* y = posed.data() + static_cast<size_t>(i) * 3 * V + 3 * v;
        const T* t = transl ? transl + 3 * static_cast<size_t>(f0 + i) : nullptr;
        T* out = vertices + (static_cast<size_t>(f0 + i) * V + v) * 3;
        for (int r = 0; r < 3; ++r) {
          out[r] = M[4 * r] * y[0] + M[4 * r + 1] * y[1] + M[4 * r + 2] * y[2] + M[4 * r + 3] + (t ? t[r] : T(0));
        }
      }
    }
  }
}

template void Forward<float>(const BodyModel&, int, const float*, const float*, bool, const float*, float*, float*);
template void Forward<double>(const BodyModel&, int, const double*, const double*, bool, const double*, double*,
                              double*);

}  // namespace m3c::body
