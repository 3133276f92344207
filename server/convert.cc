#include "server/convert.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <utility>

#include "absl/strings/str_cat.h"

namespace twist::server {
namespace {

bool Finite(double v) { return std::isfinite(v); }

std::string SizeText(int w, int h) { return absl::StrCat(w, "x", h); }

std::string MatTypeText(const cv::Mat& m) {
  switch (m.type()) {
    case CV_8UC1:
      return "8-bit gray";
    case CV_8UC3:
      return "8-bit colour";
    case CV_16UC1:
      return "16-bit gray";
    case CV_32SC1:
      return "int32";
    case CV_32FC2:
      return "float32x2";
    default:
      return absl::StrCat("OpenCV type ", m.type());
  }
}

uint32_t ReadBigEndian32(const std::string& s, size_t offset) {
  const auto* p = reinterpret_cast<const unsigned char*>(s.data() + offset);
  return (uint32_t{p[0]} << 24) | (uint32_t{p[1]} << 16) | (uint32_t{p[2]} << 8) | uint32_t{p[3]};
}

// Checks a PNG's IHDR before decoding (size and a sane header).
absl::Status CheckPngHeader(const std::string& data,
                            const std::string& what,
                            int expected_width,
                            int expected_height) {
  static constexpr unsigned char kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  if (data.size() < 33 || std::memcmp(data.data(), kSignature, 8) != 0 ||
      std::memcmp(data.data() + 12, "IHDR", 4) != 0) {
    return absl::InvalidArgumentError(absl::StrCat(what, ": data is not a PNG file"));
  }
  const uint32_t width = ReadBigEndian32(data, 16);
  const uint32_t height = ReadBigEndian32(data, 20);
  if (expected_width > 0 && expected_height > 0 &&
      (width != static_cast<uint32_t>(expected_width) ||
       height != static_cast<uint32_t>(expected_height))) {
    return absl::InvalidArgumentError(absl::StrCat(what,
                                                   " is ",
                                                   width,
                                                   "x",
                                                   height,
                                                   ", session expects ",
                                                   SizeText(expected_width, expected_height)));
  }
  return absl::OkStatus();
}

int PixelBytes(pb::PixelFormat f) {
  switch (f) {
    case pb::PIXEL_FORMAT_GRAY8:
      return 1;
    case pb::PIXEL_FORMAT_RGB8:
    case pb::PIXEL_FORMAT_BGR8:
      return 3;
    case pb::PIXEL_FORMAT_GRAY16:
      return 2;
    case pb::PIXEL_FORMAT_INT32:
      return 4;
    case pb::PIXEL_FORMAT_FLOAT32X2:
      return 8;
    default:
      return 0;
  }
}

int PixelCvType(pb::PixelFormat f) {
  switch (f) {
    case pb::PIXEL_FORMAT_GRAY8:
      return CV_8UC1;
    case pb::PIXEL_FORMAT_RGB8:
    case pb::PIXEL_FORMAT_BGR8:
      return CV_8UC3;
    case pb::PIXEL_FORMAT_GRAY16:
      return CV_16UC1;
    case pb::PIXEL_FORMAT_INT32:
      return CV_32SC1;
    case pb::PIXEL_FORMAT_FLOAT32X2:
      return CV_32FC2;
    default:
      return -1;
  }
}

absl::StatusOr<cv::Mat> DecodeRaw(const pb::Image& image, const std::string& what) {
  const int bpp = PixelBytes(image.pixel_format());
  if (bpp == 0) {
    return absl::InvalidArgumentError(absl::StrCat(
        what, ": RAW image needs a pixel_format (GRAY8, RGB8, BGR8, GRAY16, INT32 or FLOAT32X2)"));
  }
  if (image.width() <= 0 || image.height() <= 0) {
    return absl::InvalidArgumentError(absl::StrCat(what,
                                                   ": RAW image has size ",
                                                   image.width(),
                                                   "x",
                                                   image.height(),
                                                   "; width and height must be positive"));
  }
  const int64_t row_bytes = int64_t{image.width()} * bpp;
  const int64_t stride = image.stride() == 0 ? row_bytes : image.stride();
  if (stride < row_bytes) {
    return absl::InvalidArgumentError(
        absl::StrCat(what, ": stride ", stride, " is smaller than a row (", row_bytes, " bytes)"));
  }
  const int64_t needed = stride * (image.height() - 1) + row_bytes;
  if (static_cast<int64_t>(image.data().size()) < needed) {
    return absl::InvalidArgumentError(absl::StrCat(what,
                                                   ": RAW ",
                                                   image.width(),
                                                   "x",
                                                   image.height(),
                                                   " needs ",
                                                   needed,
                                                   " bytes, got ",
                                                   image.data().size()));
  }
  // Wrap the wire bytes without copying, then copy into an owned matrix.
  const cv::Mat view(image.height(),
                     image.width(),
                     PixelCvType(image.pixel_format()),
                     const_cast<char*>(image.data().data()),
                     static_cast<size_t>(stride));
  cv::Mat owned;
  if (image.pixel_format() == pb::PIXEL_FORMAT_RGB8) {
    cv::cvtColor(view, owned, cv::COLOR_RGB2BGR);
  } else {
    owned = view.clone();
  }
  return owned;
}

}  // namespace

// ---------------------------------------------------------------------------
// Geometry.

void ToProto(const geometry::SE3d& pose, pb::Pose* out) {
  const Eigen::Quaterniond& q = pose.unit_quaternion();
  out->mutable_rotation()->set_x(q.x());
  out->mutable_rotation()->set_y(q.y());
  out->mutable_rotation()->set_z(q.z());
  out->mutable_rotation()->set_w(q.w());
  out->mutable_translation()->set_x(pose.translation().x());
  out->mutable_translation()->set_y(pose.translation().y());
  out->mutable_translation()->set_z(pose.translation().z());
}

absl::StatusOr<geometry::SE3d> FromProto(const pb::Pose& pose) {
  const pb::Quaternion& r = pose.rotation();
  const pb::Vector3& t = pose.translation();
  for (double v : {r.x(), r.y(), r.z(), r.w(), t.x(), t.y(), t.z()}) {
    if (!Finite(v)) return absl::InvalidArgumentError("pose has a non-finite value");
  }
  const Eigen::Quaterniond q(r.w(), r.x(), r.y(), r.z());
  if (q.norm() < 1e-6) {
    return absl::InvalidArgumentError(
        "pose rotation quaternion is zero (expected unit x, y, z, w)");
  }
  return geometry::SE3d(q.normalized(), Eigen::Vector3d(t.x(), t.y(), t.z()));
}

void ToProto(const geometry::Vector6d& twist, pb::Twist* out) {
  out->mutable_linear()->set_x(twist[0]);
  out->mutable_linear()->set_y(twist[1]);
  out->mutable_linear()->set_z(twist[2]);
  out->mutable_angular()->set_x(twist[3]);
  out->mutable_angular()->set_y(twist[4]);
  out->mutable_angular()->set_z(twist[5]);
}

geometry::Vector6d FromProto(const pb::Twist& twist) {
  geometry::Vector6d xi;
  xi << twist.linear().x(), twist.linear().y(), twist.linear().z(), twist.angular().x(),
      twist.angular().y(), twist.angular().z();
  return xi;
}

void ToProto(const Eigen::Vector4d& plane, pb::Plane* out) {
  out->set_a(plane[0]);
  out->set_b(plane[1]);
  out->set_c(plane[2]);
  out->set_d(plane[3]);
}

// ---------------------------------------------------------------------------
// Session configuration.

absl::StatusOr<joints::JointType> JointTypeFromProto(pb::JointType type) {
  const int v = static_cast<int>(type);
  if (v < 1 || v > joints::kNumJointTypes) {
    return absl::InvalidArgumentError(absl::StrCat("joint type ", v, " is not a valid JointType"));
  }
  return static_cast<joints::JointType>(v - 1);
}

pb::JointType JointTypeNameToProto(const std::string& name) {
  for (int i = 0; i < joints::kNumJointTypes; ++i) {
    const auto type = static_cast<joints::JointType>(i);
    if (name == joints::JointTypeName(type)) return JointTypeToProto(type);
  }
  return pb::JOINT_TYPE_UNSPECIFIED;
}

absl::StatusOr<joints::ClassTable> ClassTableFromProto(const pb::ClassTable& table) {
  if (table.classes_size() == 0) {
    if (table.joints_size() > 0) {
      return absl::InvalidArgumentError("class table has joints but no classes");
    }
    return joints::ClassTable::CityscapesDefault();
  }
  std::vector<joints::ClassInfo> classes;
  std::map<int, size_t> index;
  for (const pb::SemanticClass& c : table.classes()) {
    if (index.count(c.id())) {
      return absl::InvalidArgumentError(absl::StrCat("class table: duplicate class id ", c.id()));
    }
    joints::ClassInfo info;
    info.id = c.id();
    info.name = c.name();
    info.is_dynamic = c.is_dynamic();
    info.fit_plane = c.fit_plane();
    index[c.id()] = classes.size();
    classes.push_back(std::move(info));
  }
  for (const pb::JointEdge& edge : table.joints()) {
    auto it = index.find(edge.child_class_id());
    if (it == index.end()) {
      return absl::InvalidArgumentError(absl::StrCat(
          "joint graph: child class ", edge.child_class_id(), " is not in the class table"));
    }
    joints::ClassInfo& child = classes[it->second];
    if (child.parent_id != -1) {
      return absl::InvalidArgumentError(absl::StrCat(
          "joint graph: class ", child.id, " (", child.name, ") has more than one joint"));
    }
    absl::StatusOr<joints::JointType> type = JointTypeFromProto(edge.joint_type());
    if (!type.ok()) {
      return absl::InvalidArgumentError(absl::StrCat(
          "joint graph: class ", child.id, " (", child.name, "): ", type.status().message()));
    }
    if (!Finite(edge.pitch())) {
      return absl::InvalidArgumentError(
          absl::StrCat("joint graph: class ", child.id, ": pitch is not finite"));
    }
    child.parent_id = edge.parent_class_id();
    child.joint = *type;
    child.pitch = edge.pitch();
  }
  // Unknown parents, cycles, dynamic parents, missing joints: the engine's
  // validation, with its messages.
  return joints::ClassTable::Create(std::move(classes));
}

absl::Status ApplyOptions(const pb::SlamOptions& in, SlamOptions* options) {
  if (in.has_num_features()) options->num_features = in.num_features();
  if (in.has_num_levels()) options->num_levels = in.num_levels();
  if (in.has_scale_factor()) {
    if (!Finite(in.scale_factor()))
      return absl::InvalidArgumentError("options.scale_factor is not finite");
    options->scale_factor = in.scale_factor();
  }
  if (in.has_fast_threshold()) options->fast_threshold = in.fast_threshold();
  if (in.has_max_depth_baselines()) {
    if (!Finite(in.max_depth_baselines())) {
      return absl::InvalidArgumentError("options.max_depth_baselines is not finite");
    }
    options->max_depth_baselines = in.max_depth_baselines();
  }
  switch (in.mapping_mode()) {
    case pb::MAPPING_MODE_UNSPECIFIED:
      break;
    case pb::MAPPING_MODE_SYNCHRONOUS:
      options->mapping_mode = MappingMode::kSynchronous;
      break;
    case pb::MAPPING_MODE_BACKGROUND:
      options->mapping_mode = MappingMode::kBackground;
      break;
    default:
      return absl::InvalidArgumentError(
          absl::StrCat("options.mapping_mode ", in.mapping_mode(), " is unknown"));
  }
  if (in.has_local_ba_iterations()) options->local_ba_iterations = in.local_ba_iterations();
  if (in.has_num_threads()) options->num_threads = in.num_threads();
  if (in.has_use_masks()) options->use_masks = in.use_masks();
  if (in.has_track_objects()) options->track_objects = in.track_objects();
  if (in.has_constrain_objects()) options->constrain_objects = in.constrain_objects();
  if (in.has_temporal_window_s()) {
    if (!Finite(in.temporal_window_s())) {
      return absl::InvalidArgumentError("options.temporal_window_s is not finite");
    }
    options->temporal_window_s = in.temporal_window_s();
  }
  if (in.has_seed()) options->seed = in.seed();
  if (in.has_object_ba_window_frames()) {
    options->object_ba_window_frames = in.object_ba_window_frames();
  }
  if (in.has_object_ba_iterations()) options->object_ba_iterations = in.object_ba_iterations();
  if (in.has_parked_objects_static()) options->parked_objects_static = in.parked_objects_static();
  if (in.has_dense_keyframes()) options->dense_keyframes = in.dense_keyframes();
  if (in.has_extra_camera_keypoints()) {
    options->extra_camera_keypoints = in.extra_camera_keypoints();
  }
  if (in.has_stereo_by_point_depth()) options->stereo_by_point_depth = in.stereo_by_point_depth();
  if (in.has_disparity_offset_px()) {
    if (!Finite(in.disparity_offset_px())) {
      return absl::InvalidArgumentError("options.disparity_offset_px is not finite");
    }
    options->disparity_offset_px = in.disparity_offset_px();
  }
  return absl::OkStatus();
}

absl::StatusOr<geometry::StereoCamera> RectifiedCameraFromProto(
    const pb::StereoCalibration& calib) {
  geometry::StereoCamera camera;
  camera.fx = calib.fx();
  camera.fy = calib.fy();
  camera.cx = calib.cx();
  camera.cy = calib.cy();
  camera.baseline = calib.baseline();
  camera.width = calib.width();
  camera.height = calib.height();
  for (double v : {camera.fx, camera.fy, camera.cx, camera.cy, camera.baseline}) {
    if (!Finite(v)) return absl::InvalidArgumentError("calibration has a non-finite value");
  }
  if (camera.width <= 0 || camera.height <= 0) {
    return absl::InvalidArgumentError(absl::StrCat(
        "calibration: image size ", camera.width, "x", camera.height, " must be positive"));
  }
  if (camera.fx <= 0 || camera.fy <= 0) {
    return absl::InvalidArgumentError(absl::StrCat(
        "calibration: focal lengths fx=", camera.fx, " fy=", camera.fy, " must be positive"));
  }
  if (camera.baseline <= 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("calibration: baseline ", camera.baseline, " m must be positive"));
  }
  if (camera.cx < 0 || camera.cx >= camera.width || camera.cy < 0 || camera.cy >= camera.height) {
    return absl::InvalidArgumentError(absl::StrCat("calibration: principal point (",
                                                   camera.cx,
                                                   ", ",
                                                   camera.cy,
                                                   ") lies outside the ",
                                                   SizeText(camera.width, camera.height),
                                                   " image"));
  }
  return camera;
}

// ---------------------------------------------------------------------------
// Frames.

absl::StatusOr<cv::Mat> DecodeImage(const pb::Image& image,
                                    const std::string& what,
                                    int expected_width,
                                    int expected_height) {
  cv::Mat mat;
  switch (image.encoding()) {
    case pb::IMAGE_ENCODING_RAW: {
      absl::StatusOr<cv::Mat> raw = DecodeRaw(image, what);
      if (!raw.ok()) return raw.status();
      mat = std::move(*raw);
      break;
    }
    case pb::IMAGE_ENCODING_PNG:
    case pb::IMAGE_ENCODING_JPEG: {
      if (image.data().empty())
        return absl::InvalidArgumentError(absl::StrCat(what, ": data is empty"));
      if (image.encoding() == pb::IMAGE_ENCODING_PNG) {
        absl::Status header = CheckPngHeader(image.data(), what, expected_width, expected_height);
        if (!header.ok()) return header;
      }
      const cv::Mat buffer(1,
                           static_cast<int>(image.data().size()),
                           CV_8UC1,
                           const_cast<char*>(image.data().data()));
      try {
        mat = cv::imdecode(buffer, cv::IMREAD_UNCHANGED);
      } catch (const cv::Exception& e) {
        return absl::InvalidArgumentError(absl::StrCat(what, ": cannot decode image: ", e.what()));
      }
      if (mat.empty()) {
        return absl::InvalidArgumentError(
            absl::StrCat(what,
                         ": cannot decode ",
                         image.encoding() == pb::IMAGE_ENCODING_PNG ? "PNG" : "JPEG",
                         " data"));
      }
      if (mat.type() == CV_8UC4) {
        cv::cvtColor(mat, mat, cv::COLOR_BGRA2BGR);
      } else if (mat.type() == CV_16UC3 || mat.type() == CV_16UC4) {
        return absl::InvalidArgumentError(
            absl::StrCat(what, ": 16-bit colour images are not supported"));
      }
      break;
    }
    default:
      return absl::InvalidArgumentError(absl::StrCat(what, ": encoding must be PNG, JPEG or RAW"));
  }
  if (expected_width > 0 && expected_height > 0 &&
      (mat.cols != expected_width || mat.rows != expected_height)) {
    return absl::InvalidArgumentError(absl::StrCat(what,
                                                   " is ",
                                                   SizeText(mat.cols, mat.rows),
                                                   ", session expects ",
                                                   SizeText(expected_width, expected_height)));
  }
  return mat;
}

absl::StatusOr<StereoFrame> FrameFromProto(const pb::Frame& frame, const FrameFormat& format) {
  StereoFrame out;
  out.index = frame.index();
  out.timestamp_ns = frame.timestamp_ns();
  if (frame.timestamp_ns() < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("timestamp_ns ", frame.timestamp_ns(), " is negative"));
  }
  if (!frame.has_left() || !frame.has_right()) {
    return absl::InvalidArgumentError(absl::StrCat(
        "frame ", frame.index(), " lacks its ", frame.has_left() ? "right" : "left", " image"));
  }
  absl::StatusOr<cv::Mat> left =
      DecodeImage(frame.left(), "left image", format.width, format.height);
  if (!left.ok()) return left.status();
  if (left->type() != CV_8UC1 && left->type() != CV_8UC3) {
    return absl::InvalidArgumentError(
        absl::StrCat("left image is ", MatTypeText(*left), "; expected 8-bit gray or colour"));
  }
  absl::StatusOr<cv::Mat> right =
      DecodeImage(frame.right(), "right image", format.width, format.height);
  if (!right.ok()) return right.status();
  if (right->type() != left->type()) {
    return absl::InvalidArgumentError(absl::StrCat(
        "right image is ", MatTypeText(*right), " but left image is ", MatTypeText(*left)));
  }
  out.left = std::move(*left);
  out.right = std::move(*right);

  if (frame.has_panoptic()) {
    absl::StatusOr<cv::Mat> mask =
        DecodeImage(frame.panoptic(), "panoptic mask", format.width, format.height);
    if (!mask.ok()) return mask.status();
    if (mask->type() != CV_16UC1 && mask->type() != CV_32SC1) {
      return absl::InvalidArgumentError(
          absl::StrCat("panoptic mask is ",
                       MatTypeText(*mask),
                       "; expected 16-bit PNG, RAW GRAY16 or RAW INT32"));
    }
    out.panoptic = std::move(*mask);
  }
  if (frame.has_flow()) {
    if (!format.allow_flow) {
      return absl::InvalidArgumentError(
          "flow is not accepted for a session with an unrectified rig (send rectified frames "
          "instead)");
    }
    if (frame.flow().encoding() != pb::IMAGE_ENCODING_RAW ||
        frame.flow().pixel_format() != pb::PIXEL_FORMAT_FLOAT32X2) {
      return absl::InvalidArgumentError("flow must be RAW FLOAT32X2");
    }
    absl::StatusOr<cv::Mat> flow = DecodeImage(frame.flow(), "flow", format.width, format.height);
    if (!flow.ok()) return flow.status();
    if (!cv::checkRange(*flow)) return absl::InvalidArgumentError("flow has non-finite values");
    out.flow = std::move(*flow);
  }
  for (const pb::DetectionBox& b : frame.boxes()) {
    if (!std::isfinite(b.x_min()) || !std::isfinite(b.y_min()) || !std::isfinite(b.x_max()) ||
        !std::isfinite(b.y_max())) {
      return absl::InvalidArgumentError("a detection box has a non-finite coordinate");
    }
    // Degenerate (zero-area) boxes happen with truncated labels and are
    // passed on as they are; only inverted boxes are malformed.
    if (b.x_max() < b.x_min() || b.y_max() < b.y_min()) {
      return absl::InvalidArgumentError(absl::StrCat("detection box (",
                                                     b.x_min(),
                                                     ", ",
                                                     b.y_min(),
                                                     ", ",
                                                     b.x_max(),
                                                     ", ",
                                                     b.y_max(),
                                                     ") is inverted (max < min)"));
    }
    DetectionBox box;
    box.class_id = b.class_id();
    box.instance_id = b.instance_id();
    box.x_min = b.x_min();
    box.y_min = b.y_min();
    box.x_max = b.x_max();
    box.y_max = b.y_max();
    out.boxes.push_back(box);
  }
  return out;
}

// ---------------------------------------------------------------------------
// Results.

pb::TrackingState TrackingStateToProto(TrackingState state) {
  switch (state) {
    case TrackingState::kNotInitialized:
      return pb::TRACKING_STATE_NOT_INITIALIZED;
    case TrackingState::kOk:
      return pb::TRACKING_STATE_OK;
    case TrackingState::kLost:
      return pb::TRACKING_STATE_LOST;
    case TrackingState::kRelocalized:
      return pb::TRACKING_STATE_RELOCALIZED;
  }
  return pb::TRACKING_STATE_UNSPECIFIED;
}

namespace {

pb::ObjectState ObjectStateToProto(ObjectState state) {
  switch (state) {
    case ObjectState::kNew:
      return pb::OBJECT_STATE_NEW;
    case ObjectState::kTracked:
      return pb::OBJECT_STATE_TRACKED;
    case ObjectState::kLost:
      return pb::OBJECT_STATE_LOST;
  }
  return pb::OBJECT_STATE_UNSPECIFIED;
}

pb::ClusterEventType ClusterEventTypeToProto(ClusterEventType type) {
  switch (type) {
    case ClusterEventType::kCreated:
      return pb::CLUSTER_EVENT_TYPE_CREATED;
    case ClusterEventType::kPlaneUpdated:
      return pb::CLUSTER_EVENT_TYPE_PLANE_UPDATED;
    case ClusterEventType::kLost:
      return pb::CLUSTER_EVENT_TYPE_LOST;
    case ClusterEventType::kRemoved:
      return pb::CLUSTER_EVENT_TYPE_REMOVED;
  }
  return pb::CLUSTER_EVENT_TYPE_UNSPECIFIED;
}

// Appends the poses [begin, end) of a trajectory.
void AddTimedPoses(const MapSnapshot::TimedPoses& trajectory,
                   size_t begin,
                   size_t end,
                   google::protobuf::RepeatedPtrField<pb::TimedPose>* out) {
  for (size_t k = begin; k < end; ++k) {
    pb::TimedPose* tp = out->Add();
    tp->set_timestamp_ns(trajectory[k].first);
    ToProto(trajectory[k].second, tp->mutable_world_from_object());
  }
}

}  // namespace

void ToProto(const FrameResult& result, pb::FrameUpdate* out) {
  out->set_index(result.index);
  out->set_timestamp_ns(result.timestamp_ns);
  out->set_tracking_state(TrackingStateToProto(result.state));
  ToProto(result.world_from_camera, out->mutable_world_from_camera());
  out->set_is_keyframe(result.is_keyframe);
  out->set_num_tracked_points(result.num_tracked_points);
  out->set_num_map_points(result.num_map_points);
  out->set_num_keyframes(result.num_keyframes);
  for (const ObjectResult& o : result.objects) {
    pb::ObjectUpdate* po = out->add_objects();
    po->set_id(o.id);
    po->set_class_id(o.class_id);
    po->set_instance_id(o.instance_id);
    po->set_state(ObjectStateToProto(o.state));
    ToProto(o.world_from_object, po->mutable_world_from_object());
    ToProto(o.twist_in_world, po->mutable_twist_in_world());
    ToProto(o.twist_in_joint, po->mutable_twist_in_joint());
    po->set_speed_mps(o.speed_mps);
    po->set_joint_type(JointTypeNameToProto(o.joint));
    po->set_num_points(o.num_points);
  }
  for (const ClusterEvent& e : result.cluster_events) {
    pb::ClusterEvent* pe = out->add_cluster_events();
    pe->set_type(ClusterEventTypeToProto(e.type));
    pe->set_cluster_id(e.cluster_id);
    pe->set_class_id(e.class_id);
    pe->set_instance_id(e.instance_id);
    pe->set_is_dynamic(e.is_dynamic);
    if (e.plane) ToProto(*e.plane, pe->mutable_plane());
  }
  for (const StageTiming& t : result.timings) {
    pb::StageTiming* pt = out->add_timings();
    pt->set_stage(t.stage);
    pt->set_ms(t.ms);
  }
}

std::vector<pb::MapChunk> MapToChunks(const MapSnapshot& map, const MapChunkOptions& options) {
  const int64_t budget = std::max<int64_t>(options.max_chunk_bytes, 4096);
  std::vector<pb::MapChunk> chunks(1);
  pb::MapSummary* summary = chunks[0].mutable_summary();
  summary->set_num_points(options.skip_points ? 0 : static_cast<int64_t>(map.points.size()));
  summary->set_num_keyframes(options.skip_keyframes ? 0
                                                    : static_cast<int64_t>(map.keyframes.size()));
  summary->set_num_clusters(options.skip_clusters ? 0 : static_cast<int64_t>(map.clusters.size()));
  summary->set_num_objects(options.skip_objects ? 0 : static_cast<int64_t>(map.objects.size()));
  summary->set_frames_processed(options.frames_processed);
  // Running estimate of the current chunk's size; a new chunk starts when the
  // next element would exceed the budget.
  int64_t used = static_cast<int64_t>(chunks[0].ByteSizeLong());
  auto room_for = [&](int64_t bytes) {
    if (used + bytes > budget && used > 16) {
      chunks.emplace_back();
      used = 0;
    }
    used += bytes;
    return &chunks.back();
  };
  if (!options.skip_points) {
    for (const MapSnapshot::Point& p : map.points) {
      pb::MapPoint mp;
      mp.set_x(p.p_in_world.x());
      mp.set_y(p.p_in_world.y());
      mp.set_z(p.p_in_world.z());
      mp.set_class_id(p.class_id);
      mp.set_cluster_id(p.cluster_id);
      const int64_t bytes = static_cast<int64_t>(mp.ByteSizeLong()) + 3;
      *room_for(bytes)->add_points() = std::move(mp);
    }
  }
  if (!options.skip_keyframes) {
    for (const MapSnapshot::KeyFrame& kf : map.keyframes) {
      pb::KeyFrame pk;
      pk.set_id(kf.id);
      pk.set_timestamp_ns(kf.timestamp_ns);
      ToProto(kf.world_from_camera, pk.mutable_world_from_camera());
      const int64_t bytes = static_cast<int64_t>(pk.ByteSizeLong()) + 3;
      *room_for(bytes)->add_keyframes() = std::move(pk);
    }
  }
  if (!options.skip_clusters) {
    for (const MapSnapshot::Cluster& c : map.clusters) {
      pb::Cluster pc;
      pc.set_id(c.id);
      pc.set_class_id(c.class_id);
      pc.set_instance_id(c.instance_id);
      pc.set_is_dynamic(c.is_dynamic);
      if (c.plane) ToProto(*c.plane, pc.mutable_plane());
      if (!options.skip_trajectories) {
        AddTimedPoses(c.trajectory, 0, c.trajectory.size(), pc.mutable_trajectory());
      }
      // A cluster with a very long trajectory may alone exceed the budget; it
      // then gets a chunk of its own (still far below the message limit).
      const int64_t bytes = static_cast<int64_t>(pc.ByteSizeLong()) + 5;
      *room_for(bytes)->add_clusters() = std::move(pc);
    }
  }
  if (!options.skip_objects) {
    // A serialized TimedPose takes ~80 bytes: pieces of at most a quarter of
    // the budget.
    const size_t poses_per_piece = static_cast<size_t>(std::max<int64_t>(budget / 320, 8));
    for (const MapSnapshot::Object& o : map.objects) {
      size_t begin = 0;
      do {
        pb::ObjectTrajectory po;
        po.set_id(o.id);
        po.set_class_id(o.class_id);
        po.set_instance_id(o.instance_id);
        po.set_cluster_id(o.cluster_id);
        const size_t end = std::min(o.trajectory.size(), begin + poses_per_piece);
        AddTimedPoses(o.trajectory, begin, end, po.mutable_trajectory());
        begin = end;
        const int64_t bytes = static_cast<int64_t>(po.ByteSizeLong()) + 5;
        *room_for(bytes)->add_objects() = std::move(po);
      } while (begin < o.trajectory.size());
    }
  }
  for (size_t i = 0; i < chunks.size(); ++i) {
    chunks[i].set_sequence(static_cast<int64_t>(i));
    chunks[i].set_last(i + 1 == chunks.size());
  }
  chunks[0].mutable_summary()->set_num_chunks(static_cast<int64_t>(chunks.size()));
  return chunks;
}

}  // namespace twist::server
