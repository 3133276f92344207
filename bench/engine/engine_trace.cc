// Per-frame trace on the KITTI clip: relative pose errors per frame pair
// (rotation split per axis in degrees), tracked points, keyframes. Diagnostic
// tool, prints only.
#include <cstdio>
#include <opencv2/calib3d.hpp>
#include "slam/features/feature_matcher.h"
#include "slam/io/metrics.h"
#include "slam/io/sequence.h"
#include "slam/system/slam_system.h"
#include "slam/common/timer.h"
#include "slam/features/orb_extractor.h"
using namespace twist;
int main(int argc, char** argv) {
  auto seq = io::OpenSequence(std::string(TWIST_SOURCE_DIR) + "/../shared/data/kitti_odometry_06_f0-50", "kitti-odometry", "06");
  SessionConfig config; config.camera = (*seq)->camera();
  if (argc > 1) config.options.num_features = atoi(argv[1]);
  // ORB micro timing
  { auto f = (*seq)->ReadFrame(0);
    features::OrbOptions o; features::OrbExtractor orb(o);
    std::vector<cv::KeyPoint> k; cv::Mat d;
    for (int r = 0; r < 5; ++r) { Stopwatch sw; orb.Extract(f->left, cv::Mat(), &k, &d); printf("orb one image %.2f ms, %zu kps\n", sw.ElapsedMs(), k.size()); }
    int lv[8]={0}; for (auto& kp : k) lv[kp.octave]++; for (int l=0;l<8;++l) printf("L%d:%d ", l, lv[l]); printf("\n");
  }
  printf("camera %s\n", config.camera.DebugString().c_str());
  if (getenv("ESSENTIAL")) {
    // Two-view rotation from the essential matrix (independent of depth) vs GT.
    features::OrbExtractor orb(features::OrbOptions{});
    const auto& gt = (*seq)->gt_world_from_camera();
    cv::Mat K = (cv::Mat_<double>(3, 3) << config.camera.fx, 0, config.camera.cx, 0, config.camera.fy, config.camera.cy, 0, 0, 1);
    std::vector<cv::KeyPoint> k0, k1; cv::Mat d0, d1;
    for (int i = 0; i + 1 < 20; ++i) {
      auto a = (*seq)->ReadFrame(i); auto b = (*seq)->ReadFrame(i + 1);
      orb.Extract(a->left, cv::Mat(), &k0, &d0); orb.Extract(b->left, cv::Mat(), &k1, &d1);
      auto m = features::MatchRatio(d0, d1, 0.7f, 50);
      std::vector<cv::Point2f> p0, p1;
      for (auto& [q, t] : m) { p0.push_back(k0[q].pt); p1.push_back(k1[t].pt); }
      cv::Mat mask; cv::Mat E = cv::findEssentialMat(p0, p1, K, cv::RANSAC, 0.999, 0.5, mask);
      cv::Mat R, t; int inl = cv::recoverPose(E, p0, p1, K, R, t, mask);
      Eigen::Matrix3d Re; for (int r = 0; r < 3; ++r) for (int c = 0; c < 3; ++c) Re(r, c) = R.at<double>(r, c);
      // R maps cam0 -> cam1 coordinates: cam1_from_cam0. GT: (gt0^-1 gt1)^-1 = cam1_from_cam0.
      geometry::SO3d Rg = (gt[i].Inverse() * gt[i + 1]).Inverse().so3();
      Eigen::Vector3d err = (Rg.Inverse() * geometry::SO3d(Re)).Log() * 180 / M_PI;
      printf("E %2d inliers %4d  rot err vs gt (%.4f %.4f %.4f) deg\n", i, inl, err.x(), err.y(), err.z());
    }
  }
  auto sys = SlamSystem::Create(config);
  std::vector<geometry::SE3d> est; std::vector<FrameResult> res;
  for (int64_t i = 0; i < (*seq)->size(); ++i) {
    auto f = (*seq)->ReadFrame(i); auto r = (*sys)->Process(*f); res.push_back(*r); est.push_back(r->world_from_camera);
  }
  auto m = io::EvaluateCamera((*seq)->gt_world_from_camera(), est);
  printf("RPE_t %.4f RPE_R %.4f ATE %.4f\n", m->rpe_t, m->rpe_r_deg, m->ate_rmse);
  const auto& gt = (*seq)->gt_world_from_camera();
  for (size_t i = 0; i + 1 < est.size(); ++i) {
    geometry::SE3d E = ((gt[i].Inverse()*gt[i+1]).Inverse()) * (est[i].Inverse()*est[i+1]);
    Eigen::Vector3d w = E.so3().Log() * 180 / M_PI;
    const Eigen::Vector3d wg = (gt[i].Inverse() * gt[i + 1]).so3().Log() * 180 / M_PI;
    const Eigen::Vector3d tg = (gt[i].Inverse() * gt[i + 1]).translation();
    printf("   gt rot (%.4f %.4f %.4f) deg, gt t (%.3f %.3f %.3f)\n", wg.x(), wg.y(), wg.z(), tg.x(), tg.y(), tg.z());
    printf("%2zu kf%d trk %4d mp %5d  t %.4f  r %.4f  (%.4f %.4f %.4f) dt %.3f %.3f %.3f\n", i+1, (int)res[i+1].is_keyframe, res[i+1].num_tracked_points, res[i+1].num_map_points,
      m->rpe_t_per_pair[i], m->rpe_r_deg_per_pair[i], w.x(), w.y(), w.z(), E.translation().x(), E.translation().y(), E.translation().z());
  }
}
