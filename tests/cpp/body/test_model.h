// A small structured SMPL-layout model for C++ tests (sparse weights, regressor rows summing to 1) and an
// independent naive LBS written with Eigen::AngleAxis and dense 4x4 transforms.
#pragma once

#include <random>
#include <vector>

#include <Eigen/Core>

#include "body/body_model.h"

namespace m3c::body::testing {

BodyModel MakeTestModel(int vertices_per_bone = 12, int num_betas = 10, unsigned seed = 0);

// vertices (V,3) and joints (J,3) for one frame, float64.
void NaiveLbs(const BodyModel& model, const double* pose, const double* betas, const double* transl,
              RowMatrixXd* vertices, RowMatrixXd* joints);

std::vector<double> RandomVector(int n, double scale, unsigned seed);

}  // namespace m3c::body::testing
