// Batched linear blend skinning of whole meshes.
#pragma once

#include "body/body_model.h"

namespace m3c::body {

// Poses N frames. pose (N, 3J) axis-angle, root first; betas (N, B), or (B) shared by all frames when
// betas_shared; transl (N, 3) or nullptr. Writes vertices (N, 3V) and joints (N, 3J); either may be nullptr.
// T is float or double; float streams the float copy of the model (half the memory traffic).
template <typename T>
void Forward(const BodyModel& model, int num_frames, const T* pose, const T* betas, bool betas_shared,
             const T* transl, T* vertices, T* joints);

}  // namespace m3c::body
