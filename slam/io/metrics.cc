#include "slam/io/metrics.h"

#include <glog/logging.h>

#include <Eigen/SVD>
#include <algorithm>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <limits>
#include <set>

#include "slam/io/json_writer.h"

namespace twist::io {
namespace {

constexpr double kRadToDeg = 180.0 / M_PI;
constexpr double kMpsToKmh = 3.6;

using Frames = std::map<int64_t, const ObjectGtRow*>;
using EstFrames = std::map<int64_t, const ObjectTrackRow*>;

double SafeDiv(double a, double b) {
  return b > 0 ? a / b : std::numeric_limits<double>::quiet_NaN();
}

std::string Num(double v, const char* fmt = "%.4f") {
  if (!std::isfinite(v)) return "-";
  char buf[48];
  std::snprintf(buf, sizeof(buf), fmt, v);
  return buf;
}

}  // namespace

double RotationAngleDeg(const geometry::SO3d& r) { return r.Log().norm() * kRadToDeg; }

namespace {

// Umeyama (1991): gt ≈ scale · R · est + t in least squares; the scale is
// fitted when `fit_scale`, else 1.
Similarity Umeyama(const std::vector<Eigen::Vector3d>& est,
                   const std::vector<Eigen::Vector3d>& gt,
                   bool fit_scale) {
  CHECK_EQ(est.size(), gt.size());
  CHECK(!est.empty());
  const double n = static_cast<double>(est.size());
  Eigen::Vector3d mu_e = Eigen::Vector3d::Zero();
  Eigen::Vector3d mu_g = Eigen::Vector3d::Zero();
  for (size_t k = 0; k < est.size(); ++k) {
    mu_e += est[k];
    mu_g += gt[k];
  }
  mu_e /= n;
  mu_g /= n;
  Eigen::Matrix3d sigma = Eigen::Matrix3d::Zero();
  double var_e = 0.0;
  for (size_t k = 0; k < est.size(); ++k) {
    sigma += (gt[k] - mu_g) * (est[k] - mu_e).transpose();
    var_e += (est[k] - mu_e).squaredNorm();
  }
  sigma /= n;
  var_e /= n;
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(sigma, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d s = Eigen::Matrix3d::Identity();
  if (svd.matrixU().determinant() * svd.matrixV().determinant() < 0) s(2, 2) = -1;
  Similarity out;
  out.rotation = svd.matrixU() * s * svd.matrixV().transpose();
  if (fit_scale && var_e > 0.0) {
    out.scale = (svd.singularValues().asDiagonal() * s).trace() / var_e;
  }
  out.translation = mu_g - out.scale * out.rotation * mu_e;
  return out;
}

}  // namespace

geometry::SE3d AlignRigid(const std::vector<Eigen::Vector3d>& est,
                          const std::vector<Eigen::Vector3d>& gt) {
  const Similarity a = Umeyama(est, gt, /*fit_scale=*/false);
  return geometry::SE3d(a.rotation, a.translation);
}

Similarity AlignSimilarity(const std::vector<Eigen::Vector3d>& est,
                           const std::vector<Eigen::Vector3d>& gt) {
  return Umeyama(est, gt, /*fit_scale=*/true);
}

VisibleMisses& VisibleMisses::operator+=(const VisibleMisses& o) {
  before_first += o.before_first;
  other_fragment += o.other_fragment;
  gap += o.gap;
  after_last += o.after_last;
  return *this;
}

absl::StatusOr<CameraMetrics> EvaluateCamera(const std::vector<geometry::SE3d>& gt,
                                             const std::vector<geometry::SE3d>& est) {
  if (gt.empty()) return absl::InvalidArgumentError("camera evaluation: no ground-truth poses");
  if (gt.size() != est.size()) {
    return absl::InvalidArgumentError("camera evaluation: " + std::to_string(est.size()) +
                                      " estimated poses for " + std::to_string(gt.size()) +
                                      " ground-truth frames");
  }
  CameraMetrics m;
  m.num_frames = static_cast<int64_t>(gt.size());
  for (size_t i = 0; i + 1 < gt.size(); ++i) {
    const geometry::SE3d gt_rel = gt[i].Inverse() * gt[i + 1];
    const geometry::SE3d est_rel = est[i].Inverse() * est[i + 1];
    const geometry::SE3d err = gt_rel.Inverse() * est_rel;
    const double et = err.translation().norm();
    const double er = RotationAngleDeg(err.so3());
    m.rpe_t_per_pair.push_back(et);
    m.rpe_r_deg_per_pair.push_back(er);
    m.rpe_t += et;
    m.rpe_r_deg += er;
    m.rpe_t_max = std::max(m.rpe_t_max, et);
    m.rpe_r_deg_max = std::max(m.rpe_r_deg_max, er);
    m.gt_path_length += gt_rel.translation().norm();
    m.est_path_length += est_rel.translation().norm();
  }
  m.num_pairs = static_cast<int64_t>(m.rpe_t_per_pair.size());
  if (m.num_pairs > 0) {
    m.rpe_t /= static_cast<double>(m.num_pairs);
    m.rpe_r_deg /= static_cast<double>(m.num_pairs);
  }
  std::vector<Eigen::Vector3d> pe, pg;
  for (size_t i = 0; i < gt.size(); ++i) {
    pe.push_back(est[i].translation());
    pg.push_back(gt[i].translation());
  }
  m.alignment = AlignRigid(pe, pg);
  double sum_sq = 0;
  for (size_t i = 0; i < gt.size(); ++i) {
    const double e = (pg[i] - m.alignment * pe[i]).norm();
    m.ate_per_frame.push_back(e);
    sum_sq += e * e;
    m.ate_mean += e;
    m.ate_max = std::max(m.ate_max, e);
  }
  m.ate_rmse = std::sqrt(sum_sq / static_cast<double>(gt.size()));
  m.ate_mean /= static_cast<double>(gt.size());
  const Similarity sim = AlignSimilarity(pe, pg);
  m.sim3_scale = sim.scale;
  double sum_sq_sim = 0;
  for (size_t i = 0; i < gt.size(); ++i) {
    sum_sq_sim += (pg[i] - (sim.scale * sim.rotation * pe[i] + sim.translation)).squaredNorm();
  }
  m.ate_sim3_rmse = std::sqrt(sum_sq_sim / static_cast<double>(gt.size()));
  return m;
}

void CountMaskPixels(int64_t frame, const cv::Mat& mask, MaskPixelCounts* counts) {
  if (mask.empty()) return;
  CHECK(mask.type() == CV_16UC1 || mask.type() == CV_32SC1);
  std::map<int64_t, int64_t> local;
  for (int y = 0; y < mask.rows; ++y) {
    if (mask.type() == CV_16UC1) {
      const uint16_t* row = mask.ptr<uint16_t>(y);
      int64_t run_value = -1, run = 0;
      for (int x = 0; x < mask.cols; ++x) {
        if (row[x] == run_value) {
          ++run;
          continue;
        }
        if (run > 0) local[run_value] += run;
        run_value = row[x];
        run = 1;
      }
      if (run > 0) local[run_value] += run;
    } else {
      const int32_t* row = mask.ptr<int32_t>(y);
      for (int x = 0; x < mask.cols; ++x) ++local[row[x]];
    }
  }
  for (const auto& [id, count] : local) (*counts)[{frame, id}] += count;
}

absl::StatusOr<ObjectEvaluation> EvaluateObjects(const std::vector<ObjectGtRow>& gt,
                                                 const std::vector<ObjectTrackRow>& est,
                                                 const std::vector<int64_t>& timestamps_ns,
                                                 const ObjectEvalOptions& options,
                                                 const MaskPixelCounts* pixel_counts) {
  // Group rows by track, rejecting duplicates.
  std::map<int64_t, Frames> gt_tracks;
  std::map<int64_t, int> gt_class;
  for (const ObjectGtRow& row : gt) {
    if (!gt_tracks[row.track_id].emplace(row.frame, &row).second) {
      return absl::InvalidArgumentError("objects_gt: object " + std::to_string(row.track_id) +
                                        " appears twice in frame " + std::to_string(row.frame));
    }
    gt_class[row.track_id] = row.class_id;
  }
  std::map<int64_t, EstFrames> est_tracks;
  for (const ObjectTrackRow& row : est) {
    if (!est_tracks[row.track_id].emplace(row.frame, &row).second) {
      return absl::InvalidArgumentError("objects.txt: track " + std::to_string(row.track_id) +
                                        " appears twice in frame " + std::to_string(row.frame));
    }
  }
  int64_t max_frame = -1;
  for (const ObjectGtRow& row : gt) max_frame = std::max(max_frame, row.frame);
  for (const ObjectTrackRow& row : est) max_frame = std::max(max_frame, row.frame);
  std::vector<int64_t> stamps = timestamps_ns;
  if (stamps.empty()) {
    for (int64_t i = 0; i <= max_frame; ++i) stamps.push_back(i * 100'000'000);
  }
  if (max_frame >= static_cast<int64_t>(stamps.size())) {
    return absl::InvalidArgumentError("object evaluation: frame " + std::to_string(max_frame) +
                                      " has no timestamp (" + std::to_string(stamps.size()) +
                                      " frames)");
  }
  auto dt_s = [&](int64_t i) { return NsToSeconds(stamps[i] - stamps[i - 1]); };

  // Associate each estimated track with a GT object.
  ObjectEvaluation eval;
  eval.num_est_tracks = static_cast<int>(est_tracks.size());
  std::map<int64_t, std::vector<int64_t>> candidates;  // gt track -> est tracks
  for (const auto& [est_id, frames] : est_tracks) {
    std::map<int64_t, int> votes;
    bool has_instance = false;
    for (const auto& [frame, row] : frames) {
      if (row->instance_id < 0) continue;
      has_instance = true;
      auto it = gt_tracks.find(row->instance_id);
      if (it != gt_tracks.end() && it->second.count(frame)) ++votes[row->instance_id];
    }
    int64_t match = -1;
    if (has_instance) {
      int best = 0;
      for (const auto& [gt_id, n] : votes) {
        if (n > best) {
          best = n;
          match = gt_id;
        }
      }
    } else {
      // Nearest GT box centre at the first frame of the track that has GT.
      for (const auto& [frame, row] : frames) {
        double best = options.max_match_distance_m;
        for (const auto& [gt_id, gt_frames] : gt_tracks) {
          auto g = gt_frames.find(frame);
          if (g == gt_frames.end()) continue;
          const double d =
              (g->second->world_from_object.translation() - row->world_from_object.translation())
                  .norm();
          if (d <= best) {
            best = d;
            match = gt_id;
          }
        }
        bool any_gt = false;
        for (const auto& [gt_id, gt_frames] : gt_tracks) any_gt |= gt_frames.count(frame) > 0;
        if (any_gt) break;
      }
    }
    if (match < 0) {
      ++eval.num_unmatched_est_tracks;
    } else {
      candidates[match].push_back(est_id);
    }
  }

  for (const auto& [gt_id, gt_frames] : gt_tracks) {
    ObjectMetrics m;
    m.gt_track_id = gt_id;
    m.class_id = gt_class[gt_id];
    m.gt_frames = static_cast<int64_t>(gt_frames.size());
    // Ground-truth speed.
    double gt_dist = 0, gt_time = 0;
    for (auto it = gt_frames.begin(); it != gt_frames.end(); ++it) {
      auto next = std::next(it);
      if (next == gt_frames.end() || next->first != it->first + 1) continue;
      gt_dist += (next->second->world_from_object.translation() -
                  it->second->world_from_object.translation())
                     .norm();
      gt_time += dt_s(next->first);
    }
    const double gt_speed = SafeDiv(gt_dist, gt_time);
    m.gt_mean_speed_kmh = std::isfinite(gt_speed) ? gt_speed * kMpsToKmh : 0.0;
    m.moving = std::isfinite(gt_speed) && gt_speed > options.moving_speed_mps;

    // Choose the associated estimated track with most frames in common.
    const std::vector<int64_t>& cands = candidates[gt_id];
    m.num_est_tracks = static_cast<int>(cands.size());
    int64_t best_overlap = 0;
    for (int64_t est_id : cands) {
      int64_t overlap = 0;
      for (const auto& [frame, row] : est_tracks[est_id]) overlap += gt_frames.count(frame);
      if (overlap > best_overlap) {
        best_overlap = overlap;
        m.est_track_id = est_id;
      }
    }
    std::set<int64_t> tracked;
    const EstFrames* e = nullptr;
    if (m.est_track_id >= 0) {
      e = &est_tracks[m.est_track_id];
      for (const auto& [frame, row] : *e) {
        if (gt_frames.count(frame)) tracked.insert(frame);
      }
    }
    m.tracked_frames = static_cast<int64_t>(tracked.size());
    m.coverage = SafeDiv(static_cast<double>(m.tracked_frames), static_cast<double>(m.gt_frames));
    if (pixel_counts != nullptr) {
      m.visible_gt_frames = 0;
      m.visible_tracked_frames = 0;
      // The frames of the object's other tracks, and the span of all of them.
      std::set<int64_t> elsewhere;
      int64_t first_any = std::numeric_limits<int64_t>::max(), last_any = -1;
      for (int64_t est_id : cands) {
        for (const auto& [frame, row] : est_tracks[est_id]) {
          if (est_id != m.est_track_id) elsewhere.insert(frame);
          first_any = std::min(first_any, frame);
          last_any = std::max(last_any, frame);
        }
      }
      const int64_t pan_id = static_cast<int64_t>(m.class_id) * 1000 + gt_id;
      for (const auto& [frame, row] : gt_frames) {
        auto it = pixel_counts->find({frame, pan_id});
        const int64_t px = it == pixel_counts->end() ? 0 : it->second;
        if (px < options.min_mask_pixels) continue;
        ++m.visible_gt_frames;
        if (tracked.count(frame)) {
          ++m.visible_tracked_frames;
        } else if (elsewhere.count(frame)) {
          ++m.visible_misses.other_fragment;
        } else if (frame < first_any) {
          ++m.visible_misses.before_first;
        } else if (frame > last_any) {
          ++m.visible_misses.after_last;
        } else {
          ++m.visible_misses.gap;
        }
      }
      m.visible_coverage = SafeDiv(static_cast<double>(m.visible_tracked_frames),
                                   static_cast<double>(m.visible_gt_frames));
    }
    if (!tracked.empty()) {
      const int64_t f0 = *tracked.begin();
      m.first_frame = f0;
      const geometry::SE3d offset =
          e->at(f0)->world_from_object.Inverse() * gt_frames.at(f0)->world_from_object;
      std::map<int64_t, geometry::SE3d> prop;
      for (int64_t f : tracked) prop[f] = e->at(f)->world_from_object * offset;
      for (int64_t f : tracked) {
        const double d =
            (prop[f].translation() - gt_frames.at(f)->world_from_object.translation()).norm();
        m.sum_sq_ate += d * d;
      }
      m.ate = std::sqrt(m.sum_sq_ate / static_cast<double>(tracked.size()));
      double speed_err_pose = 0;
      for (int64_t f : tracked) {
        if (tracked.count(f + 1)) {
          const geometry::SE3d& g0 = gt_frames.at(f)->world_from_object;
          const geometry::SE3d& g1 = gt_frames.at(f + 1)->world_from_object;
          const geometry::SE3d err =
              (g0.Inverse() * g1).Inverse() * (prop[f].Inverse() * prop[f + 1]);
          m.sum_rpe_t += err.translation().norm();
          m.sum_rpe_r_deg += RotationAngleDeg(err.so3());
          m.distance_m += (g1.translation() - g0.translation()).norm();
          ++m.num_pairs;
        }
        if (tracked.count(f - 1)) {
          const double dt = dt_s(f);
          if (!(dt > 0)) continue;
          const Eigen::Vector3d& c_prev = prop[f - 1].translation();
          const double v_gt = (gt_frames.at(f)->world_from_object.translation() -
                               gt_frames.at(f - 1)->world_from_object.translation())
                                  .norm() /
                              dt;
          const geometry::Vector6d xi = e->at(f)->twist_in_world * dt;
          const double v_twist = (geometry::SE3d::Exp(xi) * c_prev - c_prev).norm() / dt;
          const double v_pose = (prop[f].translation() - c_prev).norm() / dt;
          m.sum_speed_error_kmh += std::abs(v_twist - v_gt) * kMpsToKmh;
          speed_err_pose += std::abs(v_pose - v_gt) * kMpsToKmh;
          ++m.speed_samples;
        }
      }
      if (m.num_pairs > 0) {
        m.rpe_t_per_frame = m.sum_rpe_t / static_cast<double>(m.num_pairs);
        m.rpe_r_deg_per_frame = m.sum_rpe_r_deg / static_cast<double>(m.num_pairs);
        if (m.distance_m > 1e-3) {
          m.rpe_t_per_m = m.sum_rpe_t / m.distance_m;
          m.rpe_r_deg_per_m = m.sum_rpe_r_deg / m.distance_m;
        }
      }
      if (m.speed_samples > 0) {
        m.speed_error_kmh = m.sum_speed_error_kmh / static_cast<double>(m.speed_samples);
        m.speed_error_pose_kmh = speed_err_pose / static_cast<double>(m.speed_samples);
      }
    }
    eval.objects.push_back(m);
  }

  auto aggregate = [&](auto include) {
    ObjectAggregate a;
    double sum_sq = 0, sum_t = 0, sum_r = 0, dist = 0, speed = 0;
    int64_t ate_frames = 0, speed_samples = 0, vis_gt = 0, vis_tracked = 0;
    bool has_vis = false;
    for (const ObjectMetrics& m : eval.objects) {
      if (!include(m)) continue;
      ++a.num_objects;
      if (m.tracked_frames > 0) ++a.num_tracked;
      a.gt_frames += m.gt_frames;
      a.tracked_frames += m.tracked_frames;
      sum_sq += m.sum_sq_ate;
      ate_frames += m.tracked_frames;
      sum_t += m.sum_rpe_t;
      sum_r += m.sum_rpe_r_deg;
      dist += m.distance_m;
      speed += m.sum_speed_error_kmh;
      speed_samples += m.speed_samples;
      if (m.visible_gt_frames >= 0) {
        has_vis = true;
        vis_gt += m.visible_gt_frames;
        vis_tracked += m.visible_tracked_frames;
        a.visible_misses += m.visible_misses;
      }
    }
    a.coverage = SafeDiv(static_cast<double>(a.tracked_frames), static_cast<double>(a.gt_frames));
    if (has_vis)
      a.visible_coverage = SafeDiv(static_cast<double>(vis_tracked), static_cast<double>(vis_gt));
    if (ate_frames > 0) a.ate = std::sqrt(sum_sq / static_cast<double>(ate_frames));
    if (dist > 1e-3) {
      a.rpe_t_per_m = sum_t / dist;
      a.rpe_r_deg_per_m = sum_r / dist;
    }
    a.speed_error_kmh = SafeDiv(speed, static_cast<double>(speed_samples));
    return a;
  };
  eval.all = aggregate([](const ObjectMetrics&) { return true; });
  eval.moving = aggregate([](const ObjectMetrics& m) { return m.moving; });
  eval.static_objects = aggregate([](const ObjectMetrics& m) { return !m.moving; });
  std::set<std::pair<int, bool>> groups;  // (class, !moving): moving first
  for (const ObjectMetrics& m : eval.objects) groups.insert({m.class_id, !m.moving});
  for (const auto& [class_id, is_static] : groups) {
    const bool moving = !is_static;
    eval.by_class.push_back({class_id, moving, aggregate([&](const ObjectMetrics& m) {
                               return m.class_id == class_id && m.moving == moving;
                             })});
  }
  return eval;
}

std::string FormatCameraTable(const CameraMetrics& m) {
  std::string out;
  char buf[256];
  std::snprintf(buf,
                sizeof(buf),
                "camera: %" PRId64 " frames, %" PRId64 " pairs, ground-truth path %.2f m\n",
                m.num_frames,
                m.num_pairs,
                m.gt_path_length);
  out += buf;
  std::snprintf(buf, sizeof(buf), "  RPE_t  %10.5f m/frame   (max %.5f)\n", m.rpe_t, m.rpe_t_max);
  out += buf;
  std::snprintf(
      buf, sizeof(buf), "  RPE_R  %10.5f deg/frame (max %.5f)\n", m.rpe_r_deg, m.rpe_r_deg_max);
  out += buf;
  std::snprintf(buf,
                sizeof(buf),
                "  ATE    %10.5f m RMSE after SE(3) alignment (mean %.5f, max %.5f)\n",
                m.ate_rmse,
                m.ate_mean,
                m.ate_max);
  out += buf;
  if (m.gt_path_length > 0.0) {
    std::snprintf(buf,
                  sizeof(buf),
                  "  path   %10.5f x the ground truth's (%.2f m)\n",
                  m.est_path_length / m.gt_path_length,
                  m.est_path_length);
    out += buf;
  }
  std::snprintf(buf,
                sizeof(buf),
                "  ATE    %10.5f m RMSE after Sim(3) alignment (scale %.5f: the error besides "
                "the scale)\n",
                m.ate_sim3_rmse,
                m.sim3_scale);
  out += buf;
  return out;
}

std::string FormatObjectTable(const ObjectEvaluation& e) {
  std::string out;
  char buf[512];
  std::snprintf(buf,
                sizeof(buf),
                "objects: %zu ground-truth, %d estimated tracks (%d unassociated)\n",
                e.objects.size(),
                e.num_est_tracks,
                e.num_unmatched_est_tracks);
  out += buf;
  std::snprintf(buf,
                sizeof(buf),
                "  %6s %5s %-6s %6s %5s %6s %6s %8s %9s %9s %9s %5s\n",
                "id",
                "class",
                "motion",
                "frames",
                "est",
                "cov",
                "viscov",
                "ATE_m",
                "RPEt_m/m",
                "RPER_d/m",
                "speed_kmh",
                "frag");
  out += buf;
  for (const ObjectMetrics& m : e.objects) {
    std::snprintf(buf,
                  sizeof(buf),
                  "  %6" PRId64 " %5d %-6s %6" PRId64 " %5s %6s %6s %8s %9s %9s %9s %5d\n",
                  m.gt_track_id,
                  m.class_id,
                  m.moving ? "moving" : "static",
                  m.gt_frames,
                  m.est_track_id >= 0 ? std::to_string(m.est_track_id).c_str() : "-",
                  Num(m.coverage, "%.3f").c_str(),
                  Num(m.visible_coverage, "%.3f").c_str(),
                  Num(m.ate).c_str(),
                  Num(m.rpe_t_per_m).c_str(),
                  Num(m.rpe_r_deg_per_m).c_str(),
                  Num(m.speed_error_kmh, "%.3f").c_str(),
                  m.num_est_tracks);
    out += buf;
  }
  std::vector<std::pair<std::string, const ObjectAggregate*>> rows = {
      {"all", &e.all}, {"moving", &e.moving}, {"static", &e.static_objects}};
  for (const ClassAggregate& c : e.by_class) {
    rows.push_back(
        {"class " + std::to_string(c.class_id) + (c.moving ? " moving" : " static"), &c.aggregate});
  }
  for (const auto& [name, ap] : rows) {
    const ObjectAggregate& a = *ap;
    std::snprintf(buf,
                  sizeof(buf),
                  "  %-15s n=%d tracked=%d coverage=%s viscov=%s ATE=%s m RPE_t=%s m/m "
                  "RPE_R=%s deg/m speed_err=%s km/h\n",
                  name.c_str(),
                  a.num_objects,
                  a.num_tracked,
                  Num(a.coverage, "%.3f").c_str(),
                  Num(a.visible_coverage, "%.3f").c_str(),
                  Num(a.ate).c_str(),
                  Num(a.rpe_t_per_m).c_str(),
                  Num(a.rpe_r_deg_per_m).c_str(),
                  Num(a.speed_error_kmh, "%.3f").c_str());
    out += buf;
  }
  return out;
}

void WriteCameraJson(const CameraMetrics& m, JsonWriter* w) {
  w->BeginObject();
  w->Key("num_frames").Int(m.num_frames);
  w->Key("num_pairs").Int(m.num_pairs);
  w->Key("gt_path_length_m").Number(m.gt_path_length);
  w->Key("est_path_length_m").Number(m.est_path_length);
  w->Key("rpe_t_m_per_frame").Number(m.rpe_t);
  w->Key("rpe_r_deg_per_frame").Number(m.rpe_r_deg);
  w->Key("rpe_t_max_m").Number(m.rpe_t_max);
  w->Key("rpe_r_max_deg").Number(m.rpe_r_deg_max);
  w->Key("ate_rmse_m").Number(m.ate_rmse);
  w->Key("ate_mean_m").Number(m.ate_mean);
  w->Key("ate_max_m").Number(m.ate_max);
  w->Key("ate_sim3_rmse_m").Number(m.ate_sim3_rmse);
  w->Key("sim3_scale").Number(m.sim3_scale);
  w->EndObject();
}

namespace {
void WriteVisibleMissesJson(const VisibleMisses& v, JsonWriter* w) {
  w->BeginObject();
  w->Key("before_first").Int(v.before_first);
  w->Key("other_fragment").Int(v.other_fragment);
  w->Key("gap").Int(v.gap);
  w->Key("after_last").Int(v.after_last);
  w->EndObject();
}

void WriteAggregateJson(const ObjectAggregate& a, JsonWriter* w) {
  w->BeginObject();
  w->Key("num_objects").Int(a.num_objects);
  w->Key("num_tracked").Int(a.num_tracked);
  w->Key("gt_frames").Int(a.gt_frames);
  w->Key("tracked_frames").Int(a.tracked_frames);
  w->Key("coverage").Number(a.coverage);
  w->Key("visible_coverage").Number(a.visible_coverage);
  if (!std::isnan(a.visible_coverage)) {
    w->Key("visible_missed");
    WriteVisibleMissesJson(a.visible_misses, w);
  }
  w->Key("ate_m").Number(a.ate);
  w->Key("rpe_t_m_per_m").Number(a.rpe_t_per_m);
  w->Key("rpe_r_deg_per_m").Number(a.rpe_r_deg_per_m);
  w->Key("speed_error_kmh").Number(a.speed_error_kmh);
  w->EndObject();
}
}  // namespace

void WriteObjectsJson(const ObjectEvaluation& e, JsonWriter* w) {
  w->BeginObject();
  w->Key("num_gt_objects").Int(static_cast<int64_t>(e.objects.size()));
  w->Key("num_est_tracks").Int(e.num_est_tracks);
  w->Key("num_unassociated_est_tracks").Int(e.num_unmatched_est_tracks);
  w->Key("all");
  WriteAggregateJson(e.all, w);
  w->Key("moving");
  WriteAggregateJson(e.moving, w);
  w->Key("static");
  WriteAggregateJson(e.static_objects, w);
  w->Key("by_class").BeginArray();
  for (const ClassAggregate& c : e.by_class) {
    w->BeginObject();
    w->Key("class_id").Int(c.class_id);
    w->Key("moving").Bool(c.moving);
    w->Key("aggregate");
    WriteAggregateJson(c.aggregate, w);
    w->EndObject();
  }
  w->EndArray();
  w->Key("per_object").BeginArray();
  for (const ObjectMetrics& m : e.objects) {
    w->BeginObject();
    w->Key("gt_track_id").Int(m.gt_track_id);
    w->Key("class_id").Int(m.class_id);
    w->Key("moving").Bool(m.moving);
    w->Key("gt_mean_speed_kmh").Number(m.gt_mean_speed_kmh);
    w->Key("gt_frames").Int(m.gt_frames);
    if (m.est_track_id >= 0) {
      w->Key("est_track_id").Int(m.est_track_id);
    } else {
      w->Key("est_track_id").Null();
    }
    w->Key("num_est_tracks").Int(m.num_est_tracks);
    w->Key("first_frame").Int(m.first_frame);
    w->Key("tracked_frames").Int(m.tracked_frames);
    w->Key("coverage").Number(m.coverage);
    if (m.visible_gt_frames >= 0) {
      w->Key("visible_gt_frames").Int(m.visible_gt_frames);
      w->Key("visible_tracked_frames").Int(m.visible_tracked_frames);
      w->Key("visible_missed");
      WriteVisibleMissesJson(m.visible_misses, w);
    }
    w->Key("visible_coverage").Number(m.visible_coverage);
    w->Key("ate_m").Number(m.ate);
    w->Key("distance_m").Number(m.distance_m);
    w->Key("rpe_t_m_per_m").Number(m.rpe_t_per_m);
    w->Key("rpe_r_deg_per_m").Number(m.rpe_r_deg_per_m);
    w->Key("rpe_t_m_per_frame").Number(m.rpe_t_per_frame);
    w->Key("rpe_r_deg_per_frame").Number(m.rpe_r_deg_per_frame);
    w->Key("speed_samples").Int(m.speed_samples);
    w->Key("speed_error_kmh").Number(m.speed_error_kmh);
    w->Key("speed_error_pose_kmh").Number(m.speed_error_pose_kmh);
    w->EndObject();
  }
  w->EndArray();
  w->EndObject();
}

}  // namespace twist::io
