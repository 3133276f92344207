// Command line and --config file of twistslam-server (docs/server.md).
#pragma once

#include <string>

#include "absl/status/statusor.h"
#include "server/server.h"

namespace twist::server {

struct ParsedServerFlags {
  ServerOptions options;
  bool help = false;  // --help: print ServerUsage() and exit 0
  int verbosity = 0;  // --v N (glog VLOG level)
};

// Parses argv (argv[0] = program). Flags override the --config file (YAML or
// JSON read with cv::FileStorage), which overrides the built-in defaults.
// Unknown flags, missing values and bad numbers -> InvalidArgument naming
// the flag.
absl::StatusOr<ParsedServerFlags> ParseServerFlags(int argc, char** argv);
std::string ServerUsage();

}  // namespace twist::server
