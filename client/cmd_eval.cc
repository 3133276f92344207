// `twistslam eval --dataset DIR --format kitti-odometry|kitti-tracking --seq SEQ
//                 --est OUTDIR [--json FILE] [--refined]`
// `twistslam eval --dataset DIR --format ... --seq SEQ --write-gt-run DIR` writes
// the ground truth in the run-output format (a self-check: evaluating it gives zeros).
// Camera and object metrics of a run (DESIGN.md §6) as a table on stdout and
// optionally as JSON.
#include <filesystem>
#include <iostream>

#include "client/cli_util.h"
#include "client/commands.h"
#include "slam/io/evaluation.h"
#include "slam/io/sequence.h"

namespace twist::cli {

int EvalCommand(int argc, char** argv) {
  ArgParser parser("eval");
  parser.AddValue("dataset", "DIR", "dataset root (DESIGN.md §5 layouts)")
      .AddValue("format", "FORMAT", "kitti-odometry or kitti-tracking")
      .AddValue("seq", "SEQ", "sequence name, e.g. 06 or 0001")
      .AddValue("est",
                "OUTDIR",
                "output directory of `twistslam run` (camera.txt, objects.txt)",
                /*required=*/false)
      .AddValue("json", "FILE", "also write the metrics as JSON to FILE", /*required=*/false)
      .AddValue("moving-speed",
                "M_PER_S",
                "objects whose mean ground-truth speed exceeds this are 'moving'",
                /*required=*/false,
                "0.5")
      .AddValue("min-mask-pixels",
                "N",
                "visible-coverage counts frames where the object shows >= N mask pixels",
                /*required=*/false,
                "2000")
      .AddFlag("no-mask-pixels", "skip reading the masks (no visible-coverage figure)")
      .AddFlag("refined",
               "score the trajectories as the final map has them: the objects' as the "
               "dynamic BA left them (objects_refined.txt) and the camera corrected by the "
               "final keyframes (camera_refined.txt, when the run wrote it) instead of the "
               "per-frame poses (objects.txt, camera.txt)")
      .AddValue("write-gt-run",
                "DIR",
                "instead of evaluating, write the sequence's ground truth as run outputs into "
                "DIR (evaluating DIR then gives zeros)",
                /*required=*/false);
  std::optional<Args> args = parser.Parse(argc, argv);
  if (!args) return parser.exit_code();

  if (args->Has("est") == args->Has("write-gt-run")) {
    return Fail("eval", "give exactly one of --est OUTDIR and --write-gt-run DIR", 2);
  }
  io::RunEvalOptions options;
  const std::optional<double> moving = args->GetDouble("moving-speed", 0.5);
  if (!moving || *moving < 0) return Fail("eval", "--moving-speed must be a number >= 0", 2);
  const std::optional<int64_t> min_px = args->GetInt("min-mask-pixels", 2000);
  if (!min_px || *min_px < 0) return Fail("eval", "--min-mask-pixels must be an integer >= 0", 2);
  options.objects.moving_speed_mps = *moving;
  options.objects.min_mask_pixels = *min_px;
  options.count_mask_pixels = !args->Flag("no-mask-pixels");
  if (args->Flag("refined")) {
    options.objects_file = "objects_refined.txt";
    // Runs written before camera_refined.txt existed: the online poses.
    if (args->Has("est") &&
        std::filesystem::exists(std::filesystem::path(args->Get("est")) / "camera_refined.txt")) {
      options.camera_file = "camera_refined.txt";
    }
  }

  absl::StatusOr<io::DatasetFormat> format = io::ParseDatasetFormat(args->Get("format"));
  if (!format.ok()) return Fail("eval", std::string(format.status().message()), 2);
  absl::StatusOr<std::unique_ptr<io::SequenceReader>> sequence =
      io::OpenSequence(args->Get("dataset"), *format, args->Get("seq"));
  if (!sequence.ok()) return Fail("eval", std::string(sequence.status().message()));
  if (args->Has("write-gt-run")) {
    absl::Status s = io::WriteGroundTruthAsRun(**sequence, args->Get("write-gt-run"));
    if (!s.ok()) return Fail("eval", std::string(s.message()));
    std::cout << "wrote the ground truth of sequence " << (*sequence)->sequence() << " to "
              << args->Get("write-gt-run") << "\n";
    return 0;
  }
  absl::StatusOr<io::RunEvaluation> eval =
      io::EvaluateRunDirectory(**sequence, args->Get("est"), options);
  if (!eval.ok()) return Fail("eval", std::string(eval.status().message()));

  if (!eval->camera && !eval->objects) {
    return Fail("eval",
                "nothing to evaluate: sequence " + (*sequence)->sequence() +
                    " has no ground truth (" + eval->camera_note + "; " + eval->objects_note + ")");
  }
  std::cout << io::FormatRunEvaluation(*eval) << std::flush;
  if (args->Has("json")) {
    std::string error;
    if (!WriteFileAtomic(args->Get("json"), io::RunEvaluationJson(*eval), &error)) {
      return Fail("eval", error);
    }
  }
  return 0;
}

}  // namespace twist::cli
