// ξ = x + B δ: a 6-vector moved only inside the column space of B (6 x k,
// orthonormal columns), e.g. the range of a joint projector Π. Keeps the
// normal equations of constrained twists well conditioned (no null space).
#pragma once

#include <ceres/manifold.h>

#include <Eigen/Core>

namespace twist::objects {

class LinearSubspaceManifold final : public ceres::Manifold {
 public:
  explicit LinearSubspaceManifold(const Eigen::Matrix<double, 6, Eigen::Dynamic>& basis)
      : basis_(basis) {}
  int AmbientSize() const override { return 6; }
  int TangentSize() const override { return static_cast<int>(basis_.cols()); }
  bool Plus(const double* x, const double* delta, double* x_plus_delta) const override {
    Eigen::Map<Eigen::Matrix<double, 6, 1>> out(x_plus_delta);
    out = Eigen::Map<const Eigen::Matrix<double, 6, 1>>(x) +
          basis_ * Eigen::Map<const Eigen::VectorXd>(delta, basis_.cols());
    return true;
  }
  bool PlusJacobian(const double* /*x*/, double* jacobian) const override {
    Eigen::Map<Eigen::Matrix<double, 6, Eigen::Dynamic, Eigen::RowMajor>> j(
        jacobian, 6, basis_.cols());
    j = basis_;
    return true;
  }
  bool Minus(const double* y, const double* x, double* y_minus_x) const override {
    Eigen::Map<Eigen::VectorXd> out(y_minus_x, basis_.cols());
    out = basis_.transpose() * (Eigen::Map<const Eigen::Matrix<double, 6, 1>>(y) -
                                Eigen::Map<const Eigen::Matrix<double, 6, 1>>(x));
    return true;
  }
  bool MinusJacobian(const double* /*x*/, double* jacobian) const override {
    Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, 6, Eigen::RowMajor>> j(
        jacobian, basis_.cols(), 6);
    j = basis_.transpose();
    return true;
  }

 private:
  Eigen::Matrix<double, 6, Eigen::Dynamic> basis_;
};

}  // namespace twist::objects
