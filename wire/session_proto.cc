#include "wire/session_proto.h"

namespace twist::wire {

pb::JointType JointTypeToProto(joints::JointType type) {
  return static_cast<pb::JointType>(static_cast<int>(type) + 1);
}

void ToProto(const geometry::StereoCamera& camera, pb::StereoCalibration* out) {
  out->set_fx(camera.fx);
  out->set_fy(camera.fy);
  out->set_cx(camera.cx);
  out->set_cy(camera.cy);
  out->set_baseline(camera.baseline);
  out->set_width(camera.width);
  out->set_height(camera.height);
}

void ToProto(const joints::ClassTable& table, pb::ClassTable* out) {
  out->Clear();
  for (const joints::ClassInfo& c : table.classes()) {
    pb::SemanticClass* sc = out->add_classes();
    sc->set_id(c.id);
    sc->set_name(c.name);
    sc->set_is_dynamic(c.is_dynamic);
    sc->set_fit_plane(c.fit_plane);
    if (c.parent_id >= 0) {
      pb::JointEdge* e = out->add_joints();
      e->set_child_class_id(c.id);
      e->set_parent_class_id(c.parent_id);
      e->set_joint_type(JointTypeToProto(c.joint));
      e->set_pitch(c.pitch);
    }
  }
}

void ToProto(const SlamOptions& options, pb::SlamOptions* out) {
  out->set_num_features(options.num_features);
  out->set_num_levels(options.num_levels);
  out->set_scale_factor(options.scale_factor);
  out->set_fast_threshold(options.fast_threshold);
  out->set_max_depth_baselines(options.max_depth_baselines);
  out->set_mapping_mode(options.mapping_mode == MappingMode::kBackground
                            ? pb::MAPPING_MODE_BACKGROUND
                            : pb::MAPPING_MODE_SYNCHRONOUS);
  out->set_local_ba_iterations(options.local_ba_iterations);
  out->set_num_threads(options.num_threads);
  out->set_use_masks(options.use_masks);
  out->set_track_objects(options.track_objects);
  out->set_constrain_objects(options.constrain_objects);
  out->set_temporal_window_s(options.temporal_window_s);
  out->set_seed(options.seed);
  out->set_object_ba_window_frames(options.object_ba_window_frames);
  out->set_object_ba_iterations(options.object_ba_iterations);
  out->set_parked_objects_static(options.parked_objects_static);
  out->set_dense_keyframes(options.dense_keyframes);
  out->set_extra_camera_keypoints(options.extra_camera_keypoints);
  out->set_stereo_by_point_depth(options.stereo_by_point_depth);
  out->set_disparity_offset_px(options.disparity_offset_px);
}

}  // namespace twist::wire
