// Sub-commands of the `twistslam` command-line tool. Each returns the process
// exit code; on bad arguments or unreadable input it prints a one-line reason
// to stderr and returns non-zero, never leaving partial output that looks
// complete (write to a temp name, rename at the end).
#pragma once

namespace twist::cli {

int RunCommand(int argc, char** argv);       // twistslam run      (client/cmd_run.cc)
int EvalCommand(int argc, char** argv);      // twistslam eval     (client/cmd_eval.cc)
int GenerateCommand(int argc, char** argv);  // twistslam generate (client/cmd_generate.cc)
int PlotCommand(int argc, char** argv);      // twistslam plot     (client/cmd_plot.cc)
int MapCommand(int argc, char** argv);       // twistslam map      (client/cmd_map.cc)
int CalibrateCommand(int argc, char** argv);  // twistslam calibrate (client/cmd_calibrate.cc)

}  // namespace twist::cli
