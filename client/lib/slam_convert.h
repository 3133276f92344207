// Client-side conversions between the wire format and the engine's value
// types (for writing run outputs and building session requests). The server
// has its own (server/convert.h); the two meet only through the .proto.
#pragma once

#include <vector>

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

FrameResult FrameResultFromProto(const pb::FrameUpdate& update);
geometry::SE3d PoseFromProto(const pb::Pose& pose);

// Reassembles a map fetched in chunks.
MapSnapshot MapFromChunks(const std::vector<pb::MapChunk>& chunks);

}  // namespace twist::client
