// Per-frame trace on the KITTI clip: relative pose errors per frame pair
// (rotation split per axis in degrees), tracked points, keyframes. Diagnostic
// tool, prints only.
#include <algorithm>
#include <cstdio>
#include <ctime>
#include <opencv2/calib3d.hpp>
#include <opencv2/features2d.hpp>

#include "slam/common/timer.h"
#include "slam/features/feature_matcher.h"
#include "slam/features/orb_extractor.h"
#include "slam/features/stereo_matcher.h"
#include "slam/io/metrics.h"
#include "slam/io/run_output.h"
#include "slam/io/sequence.h"
#include "slam/system/slam_system.h"
using namespace twist;
int main(int argc, char** argv) {
  auto seq =
      io::OpenSequence(std::string(TWIST_SOURCE_DIR) + "/../shared/data/kitti_odometry_06_f0-50",
                       "kitti-odometry",
                       "06");
  SessionConfig config;
  config.camera = (*seq)->camera();
  if (argc > 1) config.options.num_features = atoi(argv[1]);
  if (getenv("THDEPTH")) config.options.max_depth_baselines = atof(getenv("THDEPTH"));
  if (getenv("BAIT")) config.options.local_ba_iterations = atoi(getenv("BAIT"));
  // ORB micro timing
  {
    auto f = (*seq)->ReadFrame(0);
    features::OrbOptions o;
    features::OrbExtractor orb(o);
    std::vector<cv::KeyPoint> k;
    cv::Mat d;
    for (int r = 0; r < 5; ++r) {
      timespec c0, c1;
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &c0);
      Stopwatch sw;
      orb.Extract(f->left, cv::Mat(), &k, &d);
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &c1);
      printf("orb one image %.2f ms wall, %.2f ms cpu, %zu kps\n",
             sw.ElapsedMs(),
             (c1.tv_sec - c0.tv_sec) * 1e3 + (c1.tv_nsec - c0.tv_nsec) * 1e-6,
             k.size());
    }
    {
      cv::Ptr<cv::ORB> cvorb = cv::ORB::create(2000);
      for (int r = 0; r < 3; ++r) {
        timespec c0, c1;
        clock_gettime(CLOCK_THREAD_CPUTIME_ID, &c0);
        cvorb->detectAndCompute(f->left, cv::noArray(), k, d);
        clock_gettime(CLOCK_THREAD_CPUTIME_ID, &c1);
        printf("opencv orb one image %.2f ms cpu\n",
               (c1.tv_sec - c0.tv_sec) * 1e3 + (c1.tv_nsec - c0.tv_nsec) * 1e-6);
      }
    }
    int lv[8] = {0};
    for (auto& kp : k) lv[kp.octave]++;
    for (int l = 0; l < 8; ++l) printf("L%d:%d ", l, lv[l]);
    printf("\n");
  }
  printf("camera %s\n", config.camera.DebugString().c_str());
  if (getenv("SGBM")) {
    // Our sub-pixel disparities vs OpenCV semi-global matching (1/16 px).
    features::OrbExtractor orb(features::OrbOptions{});
    for (int i0 : {5, 20, 35}) {
      auto a = (*seq)->ReadFrame(i0);
      std::vector<cv::KeyPoint> kl, kr;
      cv::Mat dl, dr;
      std::vector<cv::Mat> ll, lr;
      orb.Extract(a->left, cv::Mat(), &kl, &dl, &ll);
      orb.Extract(a->right, cv::Mat(), &kr, &dr, &lr);
      auto st = features::MatchStereo(config.camera, orb.pyramid(), kl, dl, kr, dr, ll, lr);
      auto sgbm = cv::StereoSGBM::create(
          0, 128, 5, 8 * 25, 32 * 25, 1, 0, 10, 100, 2, cv::StereoSGBM::MODE_SGBM);
      cv::Mat disp;
      sgbm->compute(a->left, a->right, disp);
      std::vector<double> diffs[3];
      for (size_t q = 0; q < kl.size(); ++q) {
        if (st.depth[q] <= 0) continue;
        const int x = cvRound(kl[q].pt.x), y = cvRound(kl[q].pt.y);
        const short d16 = disp.at<short>(y, x);
        if (d16 <= 0) continue;
        const double ours = kl[q].pt.x - st.u_right[q];
        const double diff = ours - d16 / 16.0;
        if (std::abs(diff) > 2) continue;
        diffs[std::min(2, kl[q].octave)].push_back(diff);
      }
      for (int l = 0; l < 3; ++l) {
        auto& d = diffs[l];
        if (d.empty()) continue;
        std::sort(d.begin(), d.end());
        double mean = 0;
        for (double v : d) mean += v;
        mean /= d.size();
        printf("frame %d level %s: %zu pts, ours - SGBM disparity: median %.3f mean %.3f px\n",
               i0,
               l == 2 ? ">=2" : std::to_string(l).c_str(),
               d.size(),
               d[d.size() / 2],
               mean);
      }
    }
  }
  if (getenv("CMPSUBPIX")) {
    // Mean disparity difference of the two sub-pixel methods on the same matches.
    features::OrbExtractor orb(features::OrbOptions{});
    for (int i0 : {5, 20, 35}) {
      auto a = (*seq)->ReadFrame(i0);
      std::vector<cv::KeyPoint> kl, kr;
      cv::Mat dl, dr;
      std::vector<cv::Mat> ll, lr;
      orb.Extract(a->left, cv::Mat(), &kl, &dl, &ll);
      orb.Extract(a->right, cv::Mat(), &kr, &dr, &lr);
      features::StereoMatchOptions o0, o1;
      o1.subpixel = features::SubpixelMethod::kSsdGaussNewton;
      auto s0 = features::MatchStereo(config.camera, orb.pyramid(), kl, dl, kr, dr, ll, lr, o0);
      auto s1 = features::MatchStereo(config.camera, orb.pyramid(), kl, dl, kr, dr, ll, lr, o1);
      double sum[8] = {0}, n[8] = {0};
      for (size_t q = 0; q < kl.size(); ++q) {
        if (s0.depth[q] <= 0 || s1.depth[q] <= 0) continue;
        const double dd = s0.u_right[q] - s1.u_right[q];  // disparity(ssd) - disparity(sad)
        if (std::abs(dd) > 1.0) continue;
        sum[kl[q].octave] += dd;
        n[kl[q].octave] += 1;
      }
      printf("frame %d: %zu keypoints, stereo matches %d (SAD) %d (SSD); disparity(SSD+GN) - "
             "disparity(SAD parabola) per level:",
             i0,
             kl.size(),
             s0.num_matches,
             s1.num_matches);
      for (int l = 0; l < 8; ++l) printf(" %.3f(%d)", n[l] ? sum[l] / n[l] : 0.0, (int)n[l]);
      printf("\n");
    }
  }
  if (getenv("DISPBIAS")) {
    // Stereo disparity vs the disparity of a two-view triangulation with the
    // ground-truth motion over 2 frames (independent of the stereo matcher).
    features::OrbExtractor orb(features::OrbOptions{});
    const auto& gt = (*seq)->gt_world_from_camera();
    for (int i0 : {16, 20, 24, 30, 36}) {
      const int i1 = i0 + 2;
      auto a = (*seq)->ReadFrame(i0);
      auto b = (*seq)->ReadFrame(i1);
      std::vector<cv::KeyPoint> kl, kr, k1;
      cv::Mat dl, dr, d1;
      std::vector<cv::Mat> ll, lr;
      orb.Extract(a->left, cv::Mat(), &kl, &dl, &ll);
      orb.Extract(a->right, cv::Mat(), &kr, &dr, &lr);
      orb.Extract(b->left, cv::Mat(), &k1, &d1);
      auto st = features::MatchStereo(config.camera, orb.pyramid(), kl, dl, kr, dr, ll, lr);
      auto m = features::MatchRatio(dl, d1, 0.7f, 50);
      const geometry::SE3d c1_from_c0 = gt[i1].Inverse() * gt[i0];
      std::vector<double> diffs;
      for (auto& [q, t] : m) {
        if (st.depth[q] <= 0 || kl[q].octave > 1) continue;
        const auto& cam = config.camera;
        Eigen::Vector2d x0((kl[q].pt.x - cam.cx) / cam.fx, (kl[q].pt.y - cam.cy) / cam.fy);
        Eigen::Vector2d x1((k1[t].pt.x - cam.cx) / cam.fx, (k1[t].pt.y - cam.cy) / cam.fy);
        auto p = geometry::TriangulateTwoView(
            geometry::SE3d().matrix3x4(), c1_from_c0.matrix3x4(), x0, x1);
        if (!p || p->z() < 3 || p->z() > 15) continue;
        diffs.push_back((kl[q].pt.x - st.u_right[q]) - cam.bf() / p->z());
      }
      std::sort(diffs.begin(), diffs.end());
      if (diffs.empty()) continue;
      printf(
          "frames %d-%d: %zu close points, disparity (stereo - triangulated) median %.3f px, p25 "
          "%.3f p75 %.3f\n",
          i0,
          i1,
          diffs.size(),
          diffs[diffs.size() / 2],
          diffs[diffs.size() / 4],
          diffs[diffs.size() * 3 / 4]);
    }
  }
  if (getenv("ESSENTIAL")) {
    // Two-view rotation from the essential matrix (independent of depth) vs GT.
    features::OrbExtractor orb(features::OrbOptions{});
    const auto& gt = (*seq)->gt_world_from_camera();
    cv::Mat K = (cv::Mat_<double>(3, 3) << config.camera.fx,
                 0,
                 config.camera.cx,
                 0,
                 config.camera.fy,
                 config.camera.cy,
                 0,
                 0,
                 1);
    std::vector<cv::KeyPoint> k0, k1;
    cv::Mat d0, d1;
    const int gap = getenv("GAP") ? atoi(getenv("GAP")) : 1;
    for (int i = 0; i + gap < 51; i += gap) {
      auto a = (*seq)->ReadFrame(i);
      auto b = (*seq)->ReadFrame(i + gap);
      orb.Extract(a->left, cv::Mat(), &k0, &d0);
      orb.Extract(b->left, cv::Mat(), &k1, &d1);
      auto m = features::MatchRatio(d0, d1, 0.8f, 64);
      std::vector<cv::Point2f> p0, p1;
      for (auto& [q, t] : m) {
        p0.push_back(k0[q].pt);
        p1.push_back(k1[t].pt);
      }
      cv::Mat mask;
      cv::Mat E = cv::findEssentialMat(p0, p1, K, cv::RANSAC, 0.999, 0.5, mask);
      cv::Mat R, t;
      int inl = cv::recoverPose(E, p0, p1, K, R, t, mask);
      Eigen::Matrix3d Re;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) Re(r, c) = R.at<double>(r, c);
      // R maps cam0 -> cam1 coordinates: cam1_from_cam0. GT: (gt0^-1 gt1)^-1 = cam1_from_cam0.
      geometry::SO3d Rg = (gt[i].Inverse() * gt[i + gap]).Inverse().so3();
      Eigen::Vector3d err = (Rg.Inverse() * geometry::SO3d(Re)).Log() * 180 / M_PI;
      // Translation direction: t is cam1_from_cam0's translation (unit);
      // the GT one is (gt_i^-1 gt_{i+gap})^-1's translation.
      const Eigen::Vector3d tg = (gt[i].Inverse() * gt[i + gap]).Inverse().translation();
      const Eigen::Vector3d te(t.at<double>(0), t.at<double>(1), t.at<double>(2));
      printf(
          "E %2d inliers %4d  rot err vs gt (%.4f %.4f %.4f) deg  t dir x/z %.5f gt %.5f y/z %.5f "
          "gt %.5f\n",
          i,
          inl,
          err.x(),
          err.y(),
          err.z(),
          te.x() / te.z(),
          tg.x() / tg.z(),
          te.y() / te.z(),
          tg.y() / tg.z());
    }
  }
  auto sys = SlamSystem::Create(config);
  std::vector<geometry::SE3d> est;
  std::vector<FrameResult> res;
  for (int64_t i = 0; i < (*seq)->size(); ++i) {
    auto f = (*seq)->ReadFrame(i);
    auto r = (*sys)->Process(*f);
    res.push_back(*r);
    est.push_back(r->world_from_camera);
  }
  auto m = io::EvaluateCamera((*seq)->gt_world_from_camera(), est);
  printf("RPE_t %.4f RPE_R %.4f ATE %.4f\n", m->rpe_t, m->rpe_r_deg, m->ate_rmse);
  {
    // Path length ratio (scale) and the mean relative translation error.
    const auto& g = (*seq)->gt_world_from_camera();
    double le = 0, lg = 0;
    Eigen::Vector3d mean_dt = Eigen::Vector3d::Zero();
    for (size_t i = 0; i + 1 < est.size(); ++i) {
      const geometry::SE3d ge = g[i].Inverse() * g[i + 1], ee = est[i].Inverse() * est[i + 1];
      le += ee.translation().norm();
      lg += ge.translation().norm();
      mean_dt += (ge.Inverse() * ee).translation();
    }
    mean_dt /= static_cast<double>(est.size() - 1);
    printf("path length est/gt %.5f, mean relative translation error (%.4f %.4f %.4f)\n",
           le / lg,
           mean_dt.x(),
           mean_dt.y(),
           mean_dt.z());
  }
  {
    // The same metrics from frame 12 on (KITTI 06's ground truth is visibly
    // interpolated over frames 0-11, see the ESSENTIAL=1 check).
    const auto& g = (*seq)->gt_world_from_camera();
    std::vector<geometry::SE3d> g2(g.begin() + 12, g.end()), e2(est.begin() + 12, est.end());
    auto m2 = io::EvaluateCamera(g2, e2);
    printf(
        "from frame 12: RPE_t %.4f RPE_R %.4f ATE %.4f\n", m2->rpe_t, m2->rpe_r_deg, m2->ate_rmse);
  }
  const auto& gt = (*seq)->gt_world_from_camera();
  {
    // Keyframe poses after mapping vs the online poses of the same frames.
    const MapSnapshot snap = (*sys)->Snapshot();
    std::vector<geometry::SE3d> g, online, mapped;
    const auto& ts = (*seq)->timestamps_ns();
    for (const auto& kf : snap.keyframes) {
      const size_t idx = std::find(ts.begin(), ts.end(), kf.timestamp_ns) - ts.begin();
      if (idx >= ts.size()) continue;
      g.push_back(gt[idx]);
      online.push_back(est[idx]);
      mapped.push_back(kf.world_from_camera);
    }
    auto mo = io::EvaluateCamera(g, online);
    auto mm = io::EvaluateCamera(g, mapped);
    // ORB-SLAM2's trajectory output: each frame relative to its reference
    // keyframe (here the newest surviving keyframe at or before it, online
    // poses), composed with that keyframe's pose after mapping.
    {
      std::vector<geometry::SE3d> refined;
      for (size_t i = 0; i < est.size(); ++i) {
        int best = -1;
        for (size_t k = 0; k < snap.keyframes.size(); ++k) {
          if (snap.keyframes[k].timestamp_ns <= ts[i] &&
              (best < 0 || snap.keyframes[k].timestamp_ns > snap.keyframes[best].timestamp_ns)) {
            best = static_cast<int>(k);
          }
        }
        if (best < 0) {
          refined.push_back(est[i]);
          continue;
        }
        const size_t ki =
            std::find(ts.begin(), ts.end(), snap.keyframes[best].timestamp_ns) - ts.begin();
        refined.push_back(snap.keyframes[best].world_from_camera * est[ki].Inverse() * est[i]);
      }
      auto mr = io::EvaluateCamera(gt, refined);
      printf("refined-keyframe trajectory: RPE_t %.4f RPE_R %.4f ATE %.4f\n",
             mr->rpe_t,
             mr->rpe_r_deg,
             mr->ate_rmse);
    }
    // camera_refined.txt: the keyframes' corrections interpolated between
    // them (io::RefineCameraWithKeyFrames).
    {
      std::vector<std::pair<int64_t, geometry::SE3d>> frames, kfs;
      for (size_t i = 0; i < est.size(); ++i) frames.push_back({ts[i], est[i]});
      for (const auto& kf : snap.keyframes) kfs.push_back({kf.timestamp_ns, kf.world_from_camera});
      auto mi = io::EvaluateCamera(gt, io::RefineCameraWithKeyFrames(frames, kfs));
      printf("camera_refined trajectory: RPE_t %.4f RPE_R %.4f ATE %.4f\n",
             mi->rpe_t,
             mi->rpe_r_deg,
             mi->ate_rmse);
    }
    printf("consecutive keyframes: RPE_t online %.4f after mapping %.4f; RPE_R %.4f / %.4f\n",
           mo->rpe_t,
           mm->rpe_t,
           mo->rpe_r_deg,
           mm->rpe_r_deg);
    printf("keyframes %zu: ATE online %.4f, after mapping %.4f\n",
           g.size(),
           mo->ate_rmse,
           mm->ate_rmse);
  }
  for (size_t i = 0; i + 1 < est.size(); ++i) {
    geometry::SE3d E = ((gt[i].Inverse() * gt[i + 1]).Inverse()) * (est[i].Inverse() * est[i + 1]);
    Eigen::Vector3d w = E.so3().Log() * 180 / M_PI;
    const Eigen::Vector3d wg = (gt[i].Inverse() * gt[i + 1]).so3().Log() * 180 / M_PI;
    const Eigen::Vector3d tg = (gt[i].Inverse() * gt[i + 1]).translation();
    printf("   gt rot (%.4f %.4f %.4f) deg, gt t (%.3f %.3f %.3f)\n",
           wg.x(),
           wg.y(),
           wg.z(),
           tg.x(),
           tg.y(),
           tg.z());
    printf("%2zu kf%d trk %4d mp %5d  t %.4f  r %.4f  (%.4f %.4f %.4f) dt %.3f %.3f %.3f\n",
           i + 1,
           (int)res[i + 1].is_keyframe,
           res[i + 1].num_tracked_points,
           res[i + 1].num_map_points,
           m->rpe_t_per_pair[i],
           m->rpe_r_deg_per_pair[i],
           w.x(),
           w.y(),
           w.z(),
           E.translation().x(),
           E.translation().y(),
           E.translation().z());
  }
}
