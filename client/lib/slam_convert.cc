#include "client/lib/slam_convert.h"

#include <google/protobuf/descriptor.h>
#include <google/protobuf/message.h>

#include "absl/strings/str_cat.h"
#include "wire/session_proto.h"

namespace twist::client {
namespace {

geometry::Vector6d TwistFromProto(const pb::Twist& t) {
  geometry::Vector6d xi;
  xi << t.linear().x(), t.linear().y(), t.linear().z(), t.angular().x(), t.angular().y(),
      t.angular().z();
  return xi;
}

std::string JointName(pb::JointType type) {
  const int v = static_cast<int>(type);
  if (v < 1 || v > joints::kNumJointTypes) return "";
  return joints::JointTypeName(static_cast<joints::JointType>(v - 1));
}

void AppendTimedPoses(const google::protobuf::RepeatedPtrField<pb::TimedPose>& poses,
                      MapSnapshot::TimedPoses* out) {
  for (const pb::TimedPose& t : poses) {
    out->emplace_back(t.timestamp_ns(), PoseFromProto(t.world_from_object()));
  }
}

}  // namespace

geometry::SE3d PoseFromProto(const pb::Pose& pose) {
  Eigen::Quaterniond q(
      pose.rotation().w(), pose.rotation().x(), pose.rotation().y(), pose.rotation().z());
  if (q.norm() < 1e-12) q = Eigen::Quaterniond::Identity();
  return geometry::SE3d(
      q.normalized(),
      Eigen::Vector3d(pose.translation().x(), pose.translation().y(), pose.translation().z()));
}

pb::SessionConfig SessionConfigToProto(const SessionConfig& config) {
  pb::SessionConfig out;
  wire::ToProto(config.camera, out.mutable_calibration());
  wire::ToProto(config.classes, out.mutable_class_table());
  wire::ToProto(config.options, out.mutable_options());
  return out;
}

absl::Status KeepOnlyOptions(const std::set<std::string>& keep, pb::SlamOptions* options) {
  const google::protobuf::Descriptor* d = options->GetDescriptor();
  for (const std::string& key : keep) {
    if (d->FindFieldByName(key) == nullptr) {
      return absl::InvalidArgumentError(
          absl::StrCat("slam.", key, " has no field in twistslam.v1.SlamOptions"));
    }
  }
  const google::protobuf::Reflection* r = options->GetReflection();
  for (int i = 0; i < d->field_count(); ++i) {
    const google::protobuf::FieldDescriptor* f = d->field(i);
    if (keep.count(f->name()) == 0) r->ClearField(options, f);
  }
  return absl::OkStatus();
}

FrameResult FrameResultFromProto(const pb::FrameUpdate& u) {
  FrameResult r;
  r.index = u.index();
  r.timestamp_ns = u.timestamp_ns();
  switch (u.tracking_state()) {
    case pb::TRACKING_STATE_OK:
      r.state = TrackingState::kOk;
      break;
    case pb::TRACKING_STATE_LOST:
      r.state = TrackingState::kLost;
      break;
    case pb::TRACKING_STATE_RELOCALIZED:
      r.state = TrackingState::kRelocalized;
      break;
    default:
      r.state = TrackingState::kNotInitialized;
  }
  r.world_from_camera = PoseFromProto(u.world_from_camera());
  r.is_keyframe = u.is_keyframe();
  r.num_tracked_points = u.num_tracked_points();
  r.num_map_points = u.num_map_points();
  r.num_keyframes = u.num_keyframes();
  for (const pb::ObjectUpdate& o : u.objects()) {
    ObjectResult obj;
    obj.id = o.id();
    obj.class_id = o.class_id();
    obj.instance_id = o.instance_id();
    obj.state = o.state() == pb::OBJECT_STATE_TRACKED ? ObjectState::kTracked
                : o.state() == pb::OBJECT_STATE_LOST  ? ObjectState::kLost
                                                      : ObjectState::kNew;
    obj.world_from_object = PoseFromProto(o.world_from_object());
    obj.twist_in_world = TwistFromProto(o.twist_in_world());
    obj.twist_in_joint = TwistFromProto(o.twist_in_joint());
    obj.speed_mps = o.speed_mps();
    obj.joint = JointName(o.joint_type());
    obj.num_points = o.num_points();
    r.objects.push_back(obj);
  }
  for (const pb::ClusterEvent& e : u.cluster_events()) {
    ClusterEvent ev;
    switch (e.type()) {
      case pb::CLUSTER_EVENT_TYPE_PLANE_UPDATED:
        ev.type = ClusterEventType::kPlaneUpdated;
        break;
      case pb::CLUSTER_EVENT_TYPE_LOST:
        ev.type = ClusterEventType::kLost;
        break;
      case pb::CLUSTER_EVENT_TYPE_REMOVED:
        ev.type = ClusterEventType::kRemoved;
        break;
      default:
        ev.type = ClusterEventType::kCreated;
    }
    ev.cluster_id = e.cluster_id();
    ev.class_id = e.class_id();
    ev.instance_id = e.instance_id();
    ev.is_dynamic = e.is_dynamic();
    if (e.has_plane())
      ev.plane = Eigen::Vector4d(e.plane().a(), e.plane().b(), e.plane().c(), e.plane().d());
    r.cluster_events.push_back(ev);
  }
  for (const pb::StageTiming& t : u.timings()) r.timings.push_back({t.stage(), t.ms()});
  return r;
}

MapSnapshot MapFromChunks(const std::vector<pb::MapChunk>& chunks) {
  MapSnapshot map;
  for (const pb::MapChunk& chunk : chunks) {
    for (const pb::MapPoint& p : chunk.points()) {
      MapSnapshot::Point point;
      point.p_in_world = Eigen::Vector3d(p.x(), p.y(), p.z());
      point.class_id = p.class_id();
      point.cluster_id = p.cluster_id();
      map.points.push_back(point);
    }
    for (const pb::KeyFrame& k : chunk.keyframes()) {
      map.keyframes.push_back({k.id(), k.timestamp_ns(), PoseFromProto(k.world_from_camera())});
    }
    for (const pb::Cluster& c : chunk.clusters()) {
      MapSnapshot::Cluster cluster;
      cluster.id = c.id();
      cluster.class_id = c.class_id();
      cluster.instance_id = c.instance_id();
      cluster.is_dynamic = c.is_dynamic();
      if (c.has_plane())
        cluster.plane = Eigen::Vector4d(c.plane().a(), c.plane().b(), c.plane().c(), c.plane().d());
      AppendTimedPoses(c.trajectory(), &cluster.trajectory);
      map.clusters.push_back(std::move(cluster));
    }
    for (const pb::ObjectTrajectory& o : chunk.objects()) {
      // The pieces of one long trajectory come one after the other.
      if (map.objects.empty() || map.objects.back().id != o.id()) {
        MapSnapshot::Object object;
        object.id = o.id();
        object.class_id = o.class_id();
        object.instance_id = o.instance_id();
        object.cluster_id = o.cluster_id();
        map.objects.push_back(std::move(object));
      }
      AppendTimedPoses(o.trajectory(), &map.objects.back().trajectory);
    }
  }
  return map;
}

}  // namespace twist::client
