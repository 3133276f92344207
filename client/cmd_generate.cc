// `twistslam generate`: writes a synthetic sequence in the
// KITTI-tracking-with-masks layout (DESIGN.md §5, docs/sim.md).
#include <unistd.h>

#include <atomic>
#include <cctype>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <string>

#include "client/cli_util.h"
#include "client/commands.h"
#include "slam/sim/scenarios.h"
#include "slam/sim/writer.h"

namespace twist::cli {
namespace {

constexpr char kCommand[] = "generate";

// Set by SIGINT/SIGTERM: the writer stops and removes its temporary output.
std::atomic<bool> g_cancel{false};
extern "C" void OnSignal(int) { g_cancel.store(true); }

ArgParser MakeParser() {
  ArgParser parser(kCommand);
  parser.AddValue("scenario", "NAME", "scenario to render (see the list below)");
  parser.AddValue("out", "DIR", "dataset root to write (created; may hold other sequences)");
  parser.AddValue("frames", "N", "number of frames (10 Hz)", /*required=*/false, "100");
  parser.AddValue("seed", "S", "random seed (0..4294967295)", /*required=*/false, "1");
  parser.AddValue("seq", "SSSS", "sequence name", /*required=*/false, "0000");
  parser.AddFlag("gray", "write 8-bit gray images instead of BGR");
  return parser;
}

std::string ScenarioList() {
  std::string out = "scenarios:\n";
  for (const sim::ScenarioInfo& info : sim::ListScenarios()) {
    out += "  " + info.name + std::string(info.name.size() < 30 ? 30 - info.name.size() : 1, ' ') +
           info.description + "\n";
  }
  return out;
}

bool ValidSequenceName(const std::string& s) {
  if (s.empty() || s.size() > 16) return false;
  for (char c : s) {
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '_' && c != '-') return false;
  }
  return true;
}

}  // namespace

int GenerateCommand(int argc, char** argv) {
  ArgParser parser = MakeParser();
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--help") == 0 || std::strcmp(argv[i], "-h") == 0) {
      std::cout << parser.Usage() << "\n" << ScenarioList();
      return 0;
    }
  }
  std::optional<Args> args = parser.Parse(argc, argv);
  if (!args) return parser.exit_code();

  const std::optional<int64_t> frames = args->GetInt("frames", 100);
  // The street grows with the distance covered: 20000 frames (33 min) keeps
  // the scene, the memory and the render time reasonable.
  if (!frames || *frames < 1 || *frames > 20000) {
    return Fail(kCommand,
                "--frames must be an integer in [1, 20000], got '" + args->Get("frames") + "'",
                2);
  }
  const std::optional<int64_t> seed = args->GetInt("seed", 1);
  if (!seed || *seed < 0 || *seed > 4294967295LL) {
    return Fail(kCommand,
                "--seed must be an integer in [0, 4294967295], got '" + args->Get("seed") + "'",
                2);
  }
  const std::string seq = args->Get("seq", "0000");
  if (!ValidSequenceName(seq)) {
    return Fail(kCommand, "--seq must be 1-16 letters, digits, '_' or '-', got '" + seq + "'", 2);
  }
  const std::string out = args->Get("out");
  if (out.empty()) return Fail(kCommand, "--out must not be empty", 2);

  absl::StatusOr<sim::Scenario> scenario = sim::MakeScenario(
      args->Get("scenario"), static_cast<uint32_t>(*seed), static_cast<int>(*frames));
  if (!scenario.ok()) return Fail(kCommand, std::string(scenario.status().message()), 2);

  sim::WriteOptions options;
  options.sequence = seq;
  options.render.gray = args->Flag("gray");
  const bool tty = isatty(STDERR_FILENO) != 0;
  auto progress = [tty](int done, int total) {
    if (tty) std::fprintf(stderr, "\rgenerate: frame %d/%d", done, total);
    if (tty && done == total) std::fprintf(stderr, "\n");
  };
  options.cancel = &g_cancel;
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  sim::WriteStats stats;
  const absl::Status status = sim::WriteSequence(*scenario, out, options, progress, &stats);
  if (!status.ok()) return Fail(kCommand, std::string(status.message()), 1);
  std::printf(
      "wrote %s sequence %s (%d frames, seed %u) to %s; median render %.0f ms/frame, total %.1f "
      "s\n",
      scenario->name.c_str(),
      seq.c_str(),
      scenario->num_frames,
      scenario->seed,
      out.c_str(),
      stats.render_ms_median,
      stats.total_ms / 1000.0);
  return 0;
}

}  // namespace twist::cli
