// Client-side conversions between the wire format and the engine's value
// types (for writing run outputs and building session requests). The server
// has its own (server/convert.h); the two meet only through the .proto.
#pragma once

#include <set>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "slam/common/frame_result.h"
#include "slam/system/slam_options.h"
#include "slam/system/slam_system.h"
#include "twistslam/v1/map.pb.h"
#include "twistslam/v1/session.pb.h"
#include "twistslam/v1/stream.pb.h"

namespace twist::client {

namespace pb = ::twistslam::v1;

// Calibration, class table + joint graph, and every option (all fields set).
pb::SessionConfig SessionConfigToProto(const SessionConfig& config);

// Clears every option not named in `keep` (the `slam:` keys of a client's
// config, which are the fields' names), so that the server's defaults apply
// to them: its --config, and mapping in the session's own thread.
// InvalidArgument, naming it, for a key that is no field of pb::SlamOptions.
absl::Status KeepOnlyOptions(const std::set<std::string>& keep, pb::SlamOptions* options);

FrameResult FrameResultFromProto(const pb::FrameUpdate& update);
geometry::SE3d PoseFromProto(const pb::Pose& pose);

// Reassembles a map fetched in chunks.
MapSnapshot MapFromChunks(const std::vector<pb::MapChunk>& chunks);

}  // namespace twist::client
