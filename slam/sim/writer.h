// Writes a scenario as a KITTI-tracking-with-masks dataset (DESIGN.md §5):
//
//   DIR/image_02/SSSS/NNNNNN.png   left image (8-bit BGR, or gray)
//   DIR/image_03/SSSS/NNNNNN.png   right image
//   DIR/panoptic/SSSS/NNNNNN.png   16-bit class*1000+instance of the left image
//   DIR/calib/SSSS.txt             P0..P3, R_rect, Tr_velo_cam, Tr_imu_velo
//   DIR/poses/SSSS.txt             world_from_left-camera, 3x4 row-major per frame
//   DIR/times/SSSS.txt             seconds, one per frame
//   DIR/label_02/SSSS.txt          KITTI tracking labels, track id = mask instance id
//   DIR/objects_gt/SSSS.txt        frame track_id class tx ty tz qx qy qz qw (world_from_object,
//                                  origin at the 3D box centre)
//   DIR/classes.txt                class table
//
// Output is atomic: everything is written under a temporary directory and
// renamed into place at the end, so a failed run never leaves a sequence
// that looks complete.
#pragma once

#include <atomic>
#include <functional>
#include <string>

#include "absl/status/status.h"
#include "slam/geometry/stereo_camera.h"
#include "slam/sim/renderer.h"
#include "slam/sim/scenarios.h"

namespace twist::sim {

struct WriteOptions {
  std::string sequence = "0000";  // SSSS
  RenderOptions render;
  int png_compression = 1;  // 0..9 (zlib level): 1 is fast and still compact
  // Checked before every frame: when it becomes true, writing stops with
  // kCancelled and the temporary directory is removed (e.g. set from a
  // SIGINT handler). Not owned; may be null.
  const std::atomic<bool>* cancel = nullptr;
};

// Timing of a written sequence (wall clock, informative only).
struct WriteStats {
  double render_ms_median = 0.0;
  double total_ms = 0.0;
};

// Renders every frame of `scenario` and writes the dataset into `out_dir`.
// `out_dir` may be absent, empty, or an existing dataset that does not yet
// contain the sequence. `progress` (optional) is called after each frame.
absl::Status WriteSequence(const Scenario& scenario,
                           const std::string& out_dir,
                           const WriteOptions& options,
                           const std::function<void(int done, int total)>& progress = nullptr,
                           WriteStats* stats = nullptr);

// KITTI tracking calibration text of a rectified rig (P2 = left, P3 = right
// with P3[0,3] = -fx·baseline; P0/P1 equal P2/P3, so the reference camera is
// the left camera and label locations need no offset).
std::string CalibrationText(const geometry::StereoCamera& camera);

// The class table of the generated data (docs/config.md format, written
// by joints::ClassTable::ToText).
std::string ClassTableText();

// Per-eye exposure of frame `frame` (deterministic in the scenario seed):
// the right camera has a slightly different gain and offset.
void FrameExposures(const Scenario& scenario, int frame, Exposure* left, Exposure* right);

}  // namespace twist::sim
