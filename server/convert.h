// Every conversion between the wire format (twistslam.v1) and the engine's
// types (slam/) lives here, so the whole wire format is in one file pair.
// Functions never CHECK on client data: malformed input returns
// InvalidArgument with a message that says what is wrong.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "slam/common/frame_result.h"
#include "slam/common/stereo_frame.h"
#include "slam/geometry/se3.h"
#include "slam/geometry/stereo_camera.h"
#include "slam/joints/class_table.h"
#include "slam/system/slam_options.h"
#include "slam/system/slam_system.h"
#include "twistslam/v1/map.pb.h"
#include "twistslam/v1/session.pb.h"
#include "twistslam/v1/stream.pb.h"
#include "wire/session_proto.h"

namespace twist::server {

namespace pb = ::twistslam::v1;

// ---------------------------------------------------------------------------
// Geometry.
void ToProto(const geometry::SE3d& pose, pb::Pose* out);
// Rejects non-finite values and a (near-)zero quaternion; renormalises.
absl::StatusOr<geometry::SE3d> FromProto(const pb::Pose& pose);
void ToProto(const geometry::Vector6d& twist, pb::Twist* out);  // (v, ω)
geometry::Vector6d FromProto(const pb::Twist& twist);
void ToProto(const Eigen::Vector4d& plane, pb::Plane* out);

// ---------------------------------------------------------------------------
// Session configuration.
// Calibration, class table and options to the wire: the client's too
// (wire/session_proto.h).
using wire::JointTypeToProto;
using wire::ToProto;
absl::StatusOr<joints::JointType> JointTypeFromProto(pb::JointType type);
// Engine joint names ("planar", ...) -> enum; JOINT_TYPE_UNSPECIFIED if unknown.
pb::JointType JointTypeNameToProto(const std::string& name);

// Builds and validates the class table + joint graph; empty -> Cityscapes
// defaults.
absl::StatusOr<joints::ClassTable> ClassTableFromProto(const pb::ClassTable& table);

// Overrides the fields set in `in` on top of `*options` (the server's
// defaults). Range checks are the engine's (SessionConfig::Validate via
// SlamSystem::Create); this only rejects values that cannot be represented.
absl::Status ApplyOptions(const pb::SlamOptions& in, SlamOptions* options);

// The rectified camera described by fx..height (unrectified part ignored).
// Checks the values the way StereoCamera::Validate does, with messages.
absl::StatusOr<geometry::StereoCamera> RectifiedCameraFromProto(const pb::StereoCalibration& calib);

// ---------------------------------------------------------------------------
// Frames.

// What a session accepts for its incoming images.
struct FrameFormat {
  int width = 0;  // size of incoming images (before any rectification)
  int height = 0;
  bool allow_flow = true;  // false for unrectified rigs
};

// Decodes one wire image (PNG/JPEG/RAW) into an owned cv::Mat, without role
// checks: 8-bit gray -> CV_8UC1, colour -> CV_8UC3 BGR (alpha dropped),
// 16-bit gray -> CV_16UC1, RAW INT32 -> CV_32SC1, RAW FLOAT32X2 -> CV_32FC2.
// `what` names the field in error messages ("left image").
// `expected_width/height` (> 0) are checked before decoding a PNG, so a huge
// image is rejected without allocating it.
absl::StatusOr<cv::Mat> DecodeImage(const pb::Image& image,
                                    const std::string& what,
                                    int expected_width,
                                    int expected_height);

// Decodes and validates a whole frame against the session's format: both
// images present, same size (the session's) and type (gray or colour),
// mask 16-bit or int32 of the same size, flow float32x2 of the same size,
// finite and ordered boxes.
absl::StatusOr<StereoFrame> FrameFromProto(const pb::Frame& frame, const FrameFormat& format);

// ---------------------------------------------------------------------------
// Results.
pb::TrackingState TrackingStateToProto(TrackingState state);
void ToProto(const FrameResult& result, pb::FrameUpdate* out);

// Splits a map snapshot into chunks of at most ~max_chunk_bytes serialized
// bytes. Chunk 0 carries the summary; the last chunk has last = true. An
// object trajectory longer than a chunk's share is split into pieces with the
// same id (MapFromChunks joins them).
struct MapChunkOptions {
  int64_t max_chunk_bytes = 1 << 20;
  bool skip_points = false;
  bool skip_keyframes = false;
  bool skip_clusters = false;
  bool skip_trajectories = false;
  bool skip_objects = false;
  int64_t frames_processed = 0;
};
std::vector<pb::MapChunk> MapToChunks(const MapSnapshot& map, const MapChunkOptions& options);

}  // namespace twist::server
