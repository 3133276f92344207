// `twistslam`: command-line front end (DESIGN.md §7).
#include <cstring>
#include <iostream>
#include <string>
#include <vector>

#include <glog/logging.h>

#include "client/commands.h"

namespace {

struct Command {
  const char* name;
  const char* summary;
  int (*run)(int argc, char** argv);
};

std::vector<Command> AvailableCommands() {
  std::vector<Command> commands;
#if defined(TWIST_CMD_RUN)
  commands.push_back({"run", "stream a dataset through a server or the embedded engine",
                      &twist::cli::RunCommand});
#endif
#if defined(TWIST_CMD_EVAL)
  commands.push_back({"eval", "camera and object metrics of a run against ground truth",
                      &twist::cli::EvalCommand});
#endif
#if defined(TWIST_CMD_GENERATE)
  commands.push_back({"generate", "write a synthetic sequence with exact ground truth",
                      &twist::cli::GenerateCommand});
#endif
#if defined(TWIST_CMD_PLOT)
  commands.push_back({"plot", "PNG pictures of a run (top view, object speeds)",
                      &twist::cli::PlotCommand});
#endif
#if defined(TWIST_CMD_CALIBRATE)
  commands.push_back({"calibrate",
                      "measure the stereo rig's disparity offset (known motion)",
                      &twist::cli::CalibrateCommand});
#endif
#if defined(TWIST_CMD_MAP)
  commands.push_back({"map", "fetch a session's map from a server to PLY",
                      &twist::cli::MapCommand});
#endif
  return commands;
}

void PrintUsage(const std::vector<Command>& commands) {
  std::cerr << "usage: twistslam <command> [options]   (twistslam <command> --help)\n\ncommands:\n";
  for (const Command& c : commands) {
    std::cerr << "  " << c.name << std::string(10 - std::strlen(c.name), ' ') << c.summary << "\n";
  }
}

}  // namespace

int main(int argc, char** argv) {
  google::InitGoogleLogging(argv[0]);
  FLAGS_logtostderr = true;
  // Warnings and errors only, unless GLOG_v=N in the environment asks for
  // the engine's verbose log (VLOG(N), e.g. the tracker's per-frame path).
  FLAGS_minloglevel = FLAGS_v > 0 ? 0 : 1;
  const std::vector<Command> commands = AvailableCommands();
  if (argc < 2 || std::strcmp(argv[1], "--help") == 0 || std::strcmp(argv[1], "-h") == 0) {
    PrintUsage(commands);
    return argc < 2 ? 2 : 0;
  }
  for (const Command& c : commands) {
    if (std::strcmp(argv[1], c.name) == 0) return c.run(argc - 1, argv + 1);
  }
  std::cerr << "twistslam: unknown command '" << argv[1] << "'\n";
  PrintUsage(commands);
  return 2;
}
