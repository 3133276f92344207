#include "slam/tracking/pose_optimizer.h"

#include <Eigen/Cholesky>
#include <cmath>

namespace twist::tracking {

int OptimizePose(const geometry::StereoCamera& camera,
                 std::vector<PoseObservation>* observations,
                 geometry::SE3d* camera_from_world,
                 const PoseOptimizerOptions& options) {
  auto& obs = *observations;
  const double delta_mono = std::sqrt(options.chi2_mono);
  const double delta_stereo = std::sqrt(options.chi2_stereo);
  geometry::SE3d T = *camera_from_world;
  int num_inliers = 0;

  for (int round = 0; round < options.rounds; ++round) {
    const bool robust = round < options.rounds - 1;
    for (int it = 0; it < options.iterations_per_round; ++it) {
      Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
      Eigen::Matrix<double, 6, 1> b = Eigen::Matrix<double, 6, 1>::Zero();
      int used = 0;
      const Eigen::Matrix3d R = T.rotation();
      const Eigen::Vector3d t = T.translation();
      for (const PoseObservation& o : obs) {
        if (o.outlier) continue;
        const Eigen::Vector3d pc = R * o.p_in_world + t;
        if (pc.z() <= 1e-6) continue;
        Eigen::Matrix<double, 3, 6> d_pc_d_xi;
        d_pc_d_xi.leftCols<3>().setIdentity();
        d_pc_d_xi.rightCols<3>() << 0.0, pc.z(), -pc.y(), -pc.z(), 0.0, pc.x(), pc.y(), -pc.x(),
            0.0;
        const bool stereo = o.u_right >= 0.0;
        Eigen::Vector3d uvr;
        Eigen::Matrix3d d_uvr_d_pc;
        camera.ProjectStereoChecked(pc, &uvr, &d_uvr_d_pc);
        const int m = stereo ? 3 : 2;
        Eigen::Vector3d r(
            uvr.x() - o.uv.x(), uvr.y() - o.uv.y(), stereo ? uvr.z() - o.u_right : 0.0);
        const double chi2 = r.head(m).squaredNorm() * o.inv_sigma2;
        double w = o.inv_sigma2;
        if (robust) {
          const double delta = stereo ? delta_stereo : delta_mono;
          const double e = std::sqrt(chi2);
          if (e > delta) w *= delta / e;
        }
        const Eigen::Matrix<double, 3, 6> J = d_uvr_d_pc * d_pc_d_xi;
        H.noalias() += w * J.topRows(m).transpose() * J.topRows(m);
        b.noalias() += w * J.topRows(m).transpose() * r.head(m);
        ++used;
      }
      if (used < 3) break;
      const Eigen::Matrix<double, 6, 1> delta = H.ldlt().solve(-b);
      if (!delta.allFinite()) break;
      T = geometry::SE3d::Exp(delta) * T;
      if (delta.squaredNorm() < 1e-12) break;
    }
    // Re-classify every observation (outliers may come back).
    num_inliers = 0;
    const Eigen::Matrix3d R = T.rotation();
    const Eigen::Vector3d t = T.translation();
    for (PoseObservation& o : obs) {
      const Eigen::Vector3d pc = R * o.p_in_world + t;
      if (pc.z() <= 1e-6) {
        o.outlier = true;
        continue;
      }
      Eigen::Vector3d uvr;
      camera.ProjectStereoChecked(pc, &uvr);
      const bool stereo = o.u_right >= 0.0;
      double chi2 = (uvr.head<2>() - o.uv).squaredNorm();
      if (stereo) chi2 += (uvr.z() - o.u_right) * (uvr.z() - o.u_right);
      chi2 *= o.inv_sigma2;
      o.outlier = chi2 > (stereo ? options.chi2_stereo : options.chi2_mono);
      if (!o.outlier) ++num_inliers;
    }
    if (num_inliers < 10) break;
  }
  *camera_from_world = T;
  return num_inliers;
}

}  // namespace twist::tracking
