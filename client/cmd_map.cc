// `twistslam map`: fetch a server session's map (in chunks) and write it as PLY.
#include <iostream>

#include "absl/strings/str_cat.h"
#include "client/cli_util.h"
#include "client/commands.h"
#include "client/lib/map_ply.h"
#include "client/lib/slam_client.h"
#include "client/lib/slam_convert.h"

namespace twist::cli {

std::string ReadTokenFile(const std::string& path, std::string* error);  // cmd_run.cc

int MapCommand(int argc, char** argv) {
  constexpr char kCommand[] = "map";
  ArgParser parser(kCommand);
  parser.AddValue("server", "HOST:PORT", "twistslam-server address")
      .AddValue("session", "ID", "session id")
      .AddValue("out", "FILE", "PLY file to write")
      .AddValue("resume-token",
                "TOKEN",
                "load a stored session first (ResumeSession)",
                /*required=*/false)
      .AddValue("token-file", "FILE", "bearer token for the server", false)
      .AddValue("tls-ca", "FILE", "PEM roots: connect with TLS", false);
  std::optional<Args> args = parser.Parse(argc, argv);
  if (!args) return parser.exit_code();
  client::ClientOptions options;
  options.address = args->Get("server");
  options.tls_ca_file = args->Get("tls-ca");
  std::string error;
  if (args->Has("token-file")) {
    options.token = ReadTokenFile(args->Get("token-file"), &error);
    if (options.token.empty()) return Fail(kCommand, error, 2);
  }
  absl::StatusOr<std::unique_ptr<client::SlamClient>> client = client::SlamClient::Connect(options);
  if (!client.ok()) return Fail(kCommand, std::string(client.status().message()));
  if (args->Has("resume-token")) {
    auto resumed = (*client)->ResumeSession(args->Get("session"), args->Get("resume-token"));
    if (!resumed.ok())
      return Fail(kCommand, absl::StrCat("cannot resume: ", resumed.status().message()));
  }
  client::pb::GetMapRequest request;
  request.set_session_id(args->Get("session"));
  absl::StatusOr<std::vector<client::pb::MapChunk>> chunks = (*client)->GetMap(request);
  if (!chunks.ok())
    return Fail(kCommand, absl::StrCat("cannot fetch the map: ", chunks.status().message()));
  const MapSnapshot map = client::MapFromChunks(*chunks);
  if (!WriteFileAtomic(args->Get("out"), client::MapToPly(map), &error))
    return Fail(kCommand, error);
  std::cerr << "wrote " << map.points.size() << " points and " << map.keyframes.size()
            << " keyframes (" << chunks->size() << " chunks) to " << args->Get("out") << "\n";
  return 0;
}

}  // namespace twist::cli
