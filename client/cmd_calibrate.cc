// `twistslam calibrate`: measures a stereo rig's disparity offset from a
// sequence with metric camera poses (the dataset's ground truth, or a
// trajectory from another sensor: --poses) (slam/features/disparity_offset.h,
// docs/math.md §21, §22) and prints the `slam:` line that corrects it.
#include <unistd.h>

#include <cstdio>
#include <cstring>
#include <functional>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "client/cli_util.h"
#include "client/commands.h"
#include "slam/features/disparity_offset.h"
#include "slam/io/sequence.h"
#include "slam/io/trajectory_io.h"
#include "slam/system/slam_options.h"

namespace twist::cli {
namespace {

constexpr char kCommand[] = "calibrate";

ArgParser MakeParser() {
  ArgParser parser(kCommand);
  parser.AddValue("dataset", "DIR", "dataset root (with ground-truth poses)");
  parser.AddValue("format", "FORMAT", "kitti-odometry | kitti-tracking");
  parser.AddValue("seq", "SEQ", "sequence name (06, 0001, ...)");
  parser.AddValue("first", "N", "first frame used", /*required=*/false, "0");
  parser.AddValue("frames", "N", "number of frames used (default: to the end)", false);
  parser.AddValue("poses",
                  "FILE",
                  "metric camera poses to use instead of the ground truth (KITTI format, one "
                  "line per frame of the sequence, e.g. from GNSS/INS)",
                  false);
  return parser;
}

void PrintSplit(const geometry::StereoCamera& camera,
                const std::vector<features::DisparityPair>& pairs,
                const std::string& name,
                const std::function<bool(const features::DisparityPair&)>& keep) {
  std::vector<const features::DisparityPair*> sub;
  for (const features::DisparityPair& p : pairs) {
    if (keep(p)) sub.push_back(&p);
  }
  const features::DisparityOffsetFit fit = features::FitDisparityOffset(camera, sub);
  if (!fit.ok) {
    std::printf("  %-26s %6d pairs (too few)\n", name.c_str(), fit.num_pairs);
  } else {
    std::printf("  %-26s %6d pairs  %+.3f px (+- %.3f)\n",
                name.c_str(),
                fit.num_pairs,
                fit.offset_px,
                fit.standard_error_px);
  }
}

}  // namespace

int CalibrateCommand(int argc, char** argv) {
  ArgParser parser = MakeParser();
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--help") == 0 || std::strcmp(argv[i], "-h") == 0) {
      std::cout << parser.Usage()
                << "\nEvery stereo keypoint matched between two frames 1-5 apart must have\n"
                   "depths that agree under the true motion; the disparity offset that\n"
                   "makes them agree best is the rig's correction (slam:\n"
                   "disparity_offset_px). The motion must be metric: the dataset's ground\n"
                   "truth, or --poses from another sensor. The engine's own trajectory will\n"
                   "not do (its scale is what the offset distorts). docs/math.md sections\n"
                   "21 and 22.\n";
      return 0;
    }
  }
  std::optional<Args> args = parser.Parse(argc, argv);
  if (!args) return parser.exit_code();
  absl::StatusOr<io::DatasetFormat> format = io::ParseDatasetFormat(args->Get("format"));
  if (!format.ok()) return Fail(kCommand, std::string(format.status().message()), 2);
  const std::optional<int64_t> first = args->GetInt("first", 0);
  if (!first || *first < 0) {
    return Fail(kCommand, "--first must be an integer >= 0, got '" + args->Get("first") + "'", 2);
  }
  const std::optional<int64_t> frames = args->GetInt("frames", -1);
  if (!frames || (*frames != -1 && *frames < 2)) {
    return Fail(kCommand, "--frames must be an integer >= 2, got '" + args->Get("frames") + "'", 2);
  }
  absl::StatusOr<std::unique_ptr<io::SequenceReader>> reader =
      io::OpenSequence(args->Get("dataset"), *format, args->Get("seq"));
  if (!reader.ok()) return Fail(kCommand, std::string(reader.status().message()), 1);
  const io::SequenceReader& seq = **reader;
  const std::string poses_path = args->Get("poses");
  absl::StatusOr<std::vector<geometry::SE3d>> given_poses = std::vector<geometry::SE3d>();
  if (!poses_path.empty()) given_poses = io::ReadKittiPoses(poses_path);
  if (!given_poses.ok()) return Fail(kCommand, std::string(given_poses.status().message()), 1);
  if (!poses_path.empty() && static_cast<int64_t>(given_poses->size()) != seq.size()) {
    return Fail(kCommand,
                poses_path + " has " + std::to_string(given_poses->size()) +
                    " poses, the sequence " + std::to_string(seq.size()) + " frames",
                1);
  }
  if (poses_path.empty() && !seq.has_gt_poses()) {
    return Fail(kCommand,
                "the sequence has no ground-truth poses (poses/" + args->Get("seq") +
                    ".txt): calibration needs the true camera motion (--poses FILE)",
                1);
  }
  const std::vector<geometry::SE3d>& motion =
      poses_path.empty() ? seq.gt_world_from_camera() : *given_poses;
  const int64_t total = static_cast<int64_t>(motion.size());
  if (*first + 2 > total) {
    return Fail(kCommand,
                "--first " + std::to_string(*first) + " leaves fewer than 2 of the sequence's " +
                    std::to_string(total) + " frames",
                2);
  }
  const int64_t end = *frames < 0 ? total : std::min(total, *first + *frames);
  const geometry::StereoCamera& camera = seq.camera();
  const features::OrbExtractor orb(OrbOptionsFrom(SlamOptions()));

  const bool tty = isatty(STDERR_FILENO) != 0;
  std::vector<features::StereoKeypoints> views;
  std::vector<geometry::SE3d> poses;
  for (int64_t i = *first; i < end; ++i) {
    absl::StatusOr<StereoFrame> f = seq.ReadFrame(i);
    if (!f.ok()) return Fail(kCommand, std::string(f.status().message()), 1);
    views.push_back(features::ExtractStereoKeypoints(
        orb, camera, features::ToGray(f->left), features::ToGray(f->right)));
    poses.push_back(motion[i]);
    if (tty)
      std::fprintf(stderr, "\rcalibrate: frame %lld/%lld", (long long)(i + 1), (long long)end);
  }
  if (tty) std::fprintf(stderr, "\n");

  const features::DisparityCalibration calibration =
      features::CalibrateDisparityOffset(camera, orb.pyramid(), views, poses);
  const features::DisparityPairStats& stats = calibration.stats;
  const std::vector<features::DisparityPair>& pairs = calibration.pairs;
  const features::DisparityOffsetFit& fit = calibration.fit;
  std::printf(
      "sequence %s, frames %lld-%lld: %d keypoints with stereo in two frames 1-5 apart, "
      "%zu agree with the %s motion\n",
      args->Get("seq").c_str(),
      (long long)*first,
      (long long)(end - 1),
      stats.matched,
      pairs.size(),
      poses_path.empty() ? "ground-truth" : "given");
  if (!fit.ok) {
    return Fail(kCommand,
                "too few pairs (" + std::to_string(fit.num_pairs) +
                    ", need 40): a longer sequence with textured, static scenery is needed",
                1);
  }
  std::printf("disparity offset %+.3f px (+- %.3f); robust cost %.1f at it, %.1f at 0\n",
              fit.offset_px,
              fit.standard_error_px,
              fit.cost,
              fit.cost_at_zero);
  const int n = static_cast<int>(views.size());
  if (n < 40) {
    std::printf(
        "note: %d frames; windows of ~20 frames scatter by about 0.035 px, more than the "
        "+- above: 50 frames or more give a steadier value\n",
        n);
  }
  std::printf("consistency (a rig constant reads the same everywhere):\n");
  PrintSplit(
      camera, pairs, "first half of the frames", [n](const auto& p) { return p.frame_i < n / 2; });
  PrintSplit(camera, pairs, "second half of the frames", [n](const auto& p) {
    return p.frame_i >= n / 2;
  });
  PrintSplit(camera, pairs, "levels 0-2", [](const auto& p) { return p.level <= 2; });
  PrintSplit(camera, pairs, "levels >= 3", [](const auto& p) { return p.level >= 3; });
  PrintSplit(camera, pairs, "left half of the image", [&](const auto& p) {
    return p.uv_i.x() < camera.cx;
  });
  PrintSplit(camera, pairs, "right half of the image", [&](const auto& p) {
    return p.uv_i.x() >= camera.cx;
  });
  std::printf("config (run --config, server --config):\nslam:\n  disparity_offset_px: %.3f\n",
              fit.offset_px);
  return 0;
}

}  // namespace twist::cli
