#include "slam/system/slam_options.h"

#include <algorithm>
#include <cmath>
#include <string>

namespace twist {

features::OrbOptions OrbOptionsFrom(const SlamOptions& o) {
  features::OrbOptions orb;
  orb.num_features = o.num_features;
  orb.num_levels = o.num_levels;
  orb.scale_factor = o.scale_factor;
  orb.fast_threshold = o.fast_threshold;
  orb.min_fast_threshold = std::min(7, o.fast_threshold);
  orb.favoured_on_top = o.extra_camera_keypoints;
  return orb;
}

absl::Status SlamOptions::Validate() const {
  auto bad = [](const std::string& what) { return absl::InvalidArgumentError("options: " + what); };
  if (num_features < 100 || num_features > 20000) {
    return bad("num_features must be in [100, 20000], got " + std::to_string(num_features));
  }
  if (num_levels < 1 || num_levels > 12) {
    return bad("num_levels must be in [1, 12], got " + std::to_string(num_levels));
  }
  if (!(scale_factor > 1.0 && scale_factor <= 2.0)) {
    return bad("scale_factor must be in (1, 2], got " + std::to_string(scale_factor));
  }
  if (fast_threshold < 7 || fast_threshold > 100) {
    return bad("fast_threshold must be in [7, 100], got " + std::to_string(fast_threshold));
  }
  if (!(max_depth_baselines > 1.0 && max_depth_baselines <= 1000.0)) {
    return bad("max_depth_baselines must be in (1, 1000], got " +
               std::to_string(max_depth_baselines));
  }
  if (!(disparity_offset_px >= -2.0 && disparity_offset_px <= 2.0)) {
    return bad("disparity_offset_px must be in [-2, 2], got " +
               std::to_string(disparity_offset_px));
  }
  if (mapping_mode != MappingMode::kSynchronous && mapping_mode != MappingMode::kBackground) {
    return bad("mapping_mode must be synchronous or background");
  }
  if (local_ba_iterations < 0 || local_ba_iterations > 100) {
    return bad("local_ba_iterations must be in [0, 100], got " +
               std::to_string(local_ba_iterations));
  }
  if (num_threads < 1 || num_threads > 64) {
    return bad("num_threads must be in [1, 64], got " + std::to_string(num_threads));
  }
  if (!(temporal_window_s > 0.0 && temporal_window_s <= 600.0)) {
    return bad("temporal_window_s must be in (0, 600], got " + std::to_string(temporal_window_s));
  }
  if (object_ba_window_frames != 0 &&
      (object_ba_window_frames < 3 || object_ba_window_frames > 100)) {
    return bad("object_ba_window_frames must be 0 (off) or in [3, 100], got " +
               std::to_string(object_ba_window_frames));
  }
  if (object_ba_iterations < 1 || object_ba_iterations > 50) {
    return bad("object_ba_iterations must be in [1, 50], got " +
               std::to_string(object_ba_iterations));
  }
  return absl::OkStatus();
}

absl::Status SessionConfig::Validate() const {
  if (absl::Status s = camera.Validate(); !s.ok()) return s;
  if (absl::Status s = classes.Validate(); !s.ok()) return s;
  return options.Validate();
}

}  // namespace twist
