// The engine's session settings on the wire: calibration, class table and
// options as twistslam.v1 messages. One definition for the server (which
// reports a session's effective settings) and the client (which asks for
// them), so that a new option reaches the wire in one place.
//
//   pb::SessionConfig config;
//   wire::ToProto(session.camera, config.mutable_calibration());
//   wire::ToProto(session.classes, config.mutable_class_table());
//   wire::ToProto(session.options, config.mutable_options());
#pragma once

#include "slam/geometry/stereo_camera.h"
#include "slam/joints/class_table.h"
#include "slam/system/slam_options.h"
#include "twistslam/v1/session.pb.h"

namespace twist::wire {

namespace pb = ::twistslam::v1;

// The wire enum is the engine's shifted by one (0 = unspecified).
pb::JointType JointTypeToProto(joints::JointType type);

// Every field of the engine's value set (the options' optional fields
// too); the calibration's unrectified part is left as it is.
void ToProto(const geometry::StereoCamera& camera, pb::StereoCalibration* out);
// `out` cleared first: one class per table entry, one joint per parent.
void ToProto(const joints::ClassTable& table, pb::ClassTable* out);
void ToProto(const SlamOptions& options, pb::SlamOptions* out);

}  // namespace twist::wire
