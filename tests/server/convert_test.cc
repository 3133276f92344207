#include "server/convert.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <limits>
#include <opencv2/imgcodecs.hpp>

#include "client/lib/frame_encoding.h"
#include "server/rectifier.h"
#include "server/status_util.h"
#include "tests/server/test_util.h"

namespace twist::server {
namespace {

using ::testing::HasSubstr;
using twist::testing::MakeTestFrame;

constexpr int kW = 64;
constexpr int kH = 48;

FrameFormat Format() { return FrameFormat{kW, kH, true}; }

TEST(Convert, DecodesRawPngAndJpegFrames) {
  for (pb::ImageEncoding e :
       {pb::IMAGE_ENCODING_RAW, pb::IMAGE_ENCODING_PNG, pb::IMAGE_ENCODING_JPEG}) {
    const pb::Frame frame = MakeTestFrame(3, kW, kH, 1, e, /*with_mask=*/true);
    absl::StatusOr<StereoFrame> f = FrameFromProto(frame, Format());
    ASSERT_TRUE(f.ok()) << f.status();
    EXPECT_EQ(f->index, 3);
    EXPECT_EQ(f->left.type(), CV_8UC1);
    EXPECT_EQ(f->left.size(), cv::Size(kW, kH));
    EXPECT_EQ(f->panoptic.type(), CV_16UC1);
    if (e != pb::IMAGE_ENCODING_JPEG) {
      EXPECT_EQ(cv::norm(f->left, twist::testing::TestImage(kW, kH, 1, 3), cv::NORM_INF), 0.0);
    }
  }
}

TEST(Convert, RawRgbIsConvertedToBgrAndStrideHonoured) {
  pb::Image image;
  image.set_encoding(pb::IMAGE_ENCODING_RAW);
  image.set_width(2);
  image.set_height(2);
  image.set_stride(8);  // 6 bytes of pixels + 2 of padding per row
  image.set_pixel_format(pb::PIXEL_FORMAT_RGB8);
  image.set_data(std::string("\x01\x02\x03\x04\x05\x06xx\x07\x08\x09\x0a\x0b\x0c", 14));
  absl::StatusOr<cv::Mat> m = DecodeImage(image, "left image", 2, 2);
  ASSERT_TRUE(m.ok()) << m.status();
  ASSERT_EQ(m->type(), CV_8UC3);
  EXPECT_EQ(m->at<cv::Vec3b>(0, 0), cv::Vec3b(3, 2, 1));
  EXPECT_EQ(m->at<cv::Vec3b>(1, 1), cv::Vec3b(12, 11, 10));
}

TEST(Convert, RejectsWrongSizesWithAMessage) {
  pb::Frame frame = MakeTestFrame(0, kW + 2, kH, 1, pb::IMAGE_ENCODING_PNG);
  absl::Status s = FrameFromProto(frame, Format()).status();
  EXPECT_TRUE(absl::IsInvalidArgument(s));
  EXPECT_THAT(std::string(s.message()), HasSubstr("left image is 66x48, session expects 64x48"));

  frame = MakeTestFrame(0, kW, kH + 1, 1, pb::IMAGE_ENCODING_RAW);
  s = FrameFromProto(frame, Format()).status();
  EXPECT_THAT(std::string(s.message()), HasSubstr("64x49"));
}

TEST(Convert, RejectsUndecodableAndTruncatedImages) {
  pb::Frame frame = MakeTestFrame(0, kW, kH, 1, pb::IMAGE_ENCODING_PNG);
  frame.mutable_right()->set_data("not a png at all, just text............");
  absl::Status s = FrameFromProto(frame, Format()).status();
  EXPECT_TRUE(absl::IsInvalidArgument(s));
  EXPECT_THAT(std::string(s.message()), HasSubstr("right image"));

  frame = MakeTestFrame(0, kW, kH, 1, pb::IMAGE_ENCODING_JPEG);
  frame.mutable_left()->set_data(frame.left().data().substr(0, 20));
  s = FrameFromProto(frame, Format()).status();
  EXPECT_TRUE(absl::IsInvalidArgument(s)) << s;

  frame = MakeTestFrame(0, kW, kH, 1, pb::IMAGE_ENCODING_RAW);
  frame.mutable_left()->mutable_data()->resize(100);
  s = FrameFromProto(frame, Format()).status();
  EXPECT_THAT(std::string(s.message()), HasSubstr("needs 3072 bytes, got 100"));

  frame = MakeTestFrame(0, kW, kH);
  frame.clear_right();
  EXPECT_THAT(std::string(FrameFromProto(frame, Format()).status().message()),
              HasSubstr("lacks its right image"));

  frame = MakeTestFrame(0, kW, kH);
  frame.mutable_left()->set_encoding(pb::IMAGE_ENCODING_UNSPECIFIED);
  EXPECT_TRUE(absl::IsInvalidArgument(FrameFromProto(frame, Format()).status()));
}

TEST(Convert, RejectsMaskOfWrongSizeOrType) {
  pb::Frame frame = MakeTestFrame(0, kW, kH);
  // 8-bit mask: wrong type.
  ASSERT_TRUE(client::EncodeImage(cv::Mat(kH, kW, CV_8UC1, cv::Scalar(7)),
                                  pb::IMAGE_ENCODING_PNG,
                                  frame.mutable_panoptic())
                  .ok());
  absl::Status s = FrameFromProto(frame, Format()).status();
  EXPECT_THAT(std::string(s.message()), HasSubstr("panoptic mask is 8-bit gray"));
  // 16-bit of the wrong size.
  ASSERT_TRUE(client::EncodeImage(cv::Mat(kH - 1, kW, CV_16UC1, cv::Scalar(7000)),
                                  pb::IMAGE_ENCODING_PNG,
                                  frame.mutable_panoptic())
                  .ok());
  s = FrameFromProto(frame, Format()).status();
  EXPECT_THAT(std::string(s.message()), HasSubstr("panoptic mask is 64x47"));
  // RAW int32 is fine.
  ASSERT_TRUE(client::EncodeImage(cv::Mat(kH, kW, CV_32SC1, cv::Scalar(26001)),
                                  pb::IMAGE_ENCODING_RAW,
                                  frame.mutable_panoptic())
                  .ok());
  absl::StatusOr<StereoFrame> f = FrameFromProto(frame, Format());
  ASSERT_TRUE(f.ok()) << f.status();
  EXPECT_EQ(f->panoptic.type(), CV_32SC1);
}

TEST(Convert, LeftRightTypeMismatchAndColour) {
  client::FrameImages images;
  images.left = cv::Mat(kH, kW, CV_8UC3, cv::Scalar(1, 2, 3));
  images.right = cv::Mat(kH, kW, CV_8UC1, cv::Scalar(1));
  pb::Frame frame;
  ASSERT_TRUE(client::MakeFrame(images, pb::IMAGE_ENCODING_PNG, &frame).ok());
  absl::Status s = FrameFromProto(frame, Format()).status();
  EXPECT_THAT(std::string(s.message()),
              HasSubstr("right image is 8-bit gray but left image is 8-bit colour"));
  images.right = images.left.clone();
  ASSERT_TRUE(client::MakeFrame(images, pb::IMAGE_ENCODING_PNG, &frame).ok());
  absl::StatusOr<StereoFrame> f = FrameFromProto(frame, Format());
  ASSERT_TRUE(f.ok());
  EXPECT_EQ(f->left.at<cv::Vec3b>(0, 0), cv::Vec3b(1, 2, 3));
}

TEST(Convert, FlowAndBoxes) {
  pb::Frame frame = MakeTestFrame(0, kW, kH);
  cv::Mat flow(kH, kW, CV_32FC2, cv::Scalar(0.5f, -1.0f));
  ASSERT_TRUE(client::EncodeImage(flow, pb::IMAGE_ENCODING_RAW, frame.mutable_flow()).ok());
  pb::DetectionBox* box = frame.add_boxes();
  box->set_class_id(26);
  box->set_x_min(1);
  box->set_y_min(2);
  box->set_x_max(10);
  box->set_y_max(20);
  absl::StatusOr<StereoFrame> f = FrameFromProto(frame, Format());
  ASSERT_TRUE(f.ok()) << f.status();
  EXPECT_EQ(f->flow.at<cv::Vec2f>(3, 3), cv::Vec2f(0.5f, -1.0f));
  ASSERT_EQ(f->boxes.size(), 1u);
  EXPECT_EQ(f->boxes[0].x_max, 10);

  box->set_x_max(0);
  EXPECT_THAT(std::string(FrameFromProto(frame, Format()).status().message()),
              HasSubstr("is inverted"));
  box->set_x_max(10);
  FrameFormat no_flow = Format();
  no_flow.allow_flow = false;
  EXPECT_TRUE(absl::IsInvalidArgument(FrameFromProto(frame, no_flow).status()));
  flow.at<cv::Vec2f>(0, 0)[0] = std::numeric_limits<float>::quiet_NaN();
  ASSERT_TRUE(client::EncodeImage(flow, pb::IMAGE_ENCODING_RAW, frame.mutable_flow()).ok());
  EXPECT_THAT(std::string(FrameFromProto(frame, Format()).status().message()),
              HasSubstr("non-finite"));
}

TEST(Convert, PoseAndTwistRoundTrip) {
  const geometry::SE3d pose(
      Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized())),
      Eigen::Vector3d(1, -2, 3));
  pb::Pose p;
  ToProto(pose, &p);
  absl::StatusOr<geometry::SE3d> back = FromProto(p);
  ASSERT_TRUE(back.ok());
  EXPECT_LT((back->matrix() - pose.matrix()).norm(), 1e-12);
  pb::Pose zero;
  EXPECT_TRUE(absl::IsInvalidArgument(FromProto(zero).status()));
  geometry::Vector6d xi;
  xi << 1, 2, 3, 4, 5, 6;
  pb::Twist t;
  ToProto(xi, &t);
  EXPECT_EQ(t.linear().x(), 1);
  EXPECT_EQ(t.angular().z(), 6);
  EXPECT_EQ(FromProto(t), xi);
}

TEST(Convert, ClassTableFromProtoBuildsTheJointGraph) {
  pb::ClassTable table;
  absl::StatusOr<joints::ClassTable> defaults = ClassTableFromProto(table);
  ASSERT_TRUE(defaults.ok());
  EXPECT_TRUE(defaults->IsDynamic(26));

  auto* road = table.add_classes();
  road->set_id(7);
  road->set_name("road");
  road->set_fit_plane(true);
  auto* car = table.add_classes();
  car->set_id(26);
  car->set_name("car");
  car->set_is_dynamic(true);
  auto* edge = table.add_joints();
  edge->set_child_class_id(26);
  edge->set_parent_class_id(7);
  edge->set_joint_type(pb::JOINT_TYPE_PLANAR);
  absl::StatusOr<joints::ClassTable> t = ClassTableFromProto(table);
  ASSERT_TRUE(t.ok()) << t.status();
  ASSERT_NE(t->Find(26), nullptr);
  EXPECT_EQ(t->Find(26)->joint, joints::JointType::kPlanar);
  EXPECT_EQ(t->Find(26)->parent_id, 7);

  pb::ClassTable round;
  ToProto(*t, &round);
  EXPECT_EQ(round.joints_size(), 1);
  EXPECT_EQ(round.joints(0).joint_type(), pb::JOINT_TYPE_PLANAR);

  edge->set_parent_class_id(99);  // unknown parent
  EXPECT_TRUE(absl::IsInvalidArgument(ClassTableFromProto(table).status()));
  edge->set_parent_class_id(7);
  edge->set_joint_type(pb::JOINT_TYPE_UNSPECIFIED);
  EXPECT_THAT(std::string(ClassTableFromProto(table).status().message()),
              HasSubstr("not a valid JointType"));
  edge->set_joint_type(pb::JOINT_TYPE_PLANAR);
  table.add_classes()->set_id(7);
  EXPECT_THAT(std::string(ClassTableFromProto(table).status().message()),
              HasSubstr("duplicate class id 7"));
}

TEST(Convert, JointTypesMapBothWays) {
  for (int i = 0; i < joints::kNumJointTypes; ++i) {
    const auto type = static_cast<joints::JointType>(i);
    const pb::JointType p = JointTypeToProto(type);
    EXPECT_NE(p, pb::JOINT_TYPE_UNSPECIFIED);
    EXPECT_EQ(*JointTypeFromProto(p), type);
    EXPECT_EQ(JointTypeNameToProto(joints::JointTypeName(type)), p);
  }
  EXPECT_EQ(JointTypeNameToProto("nonsense"), pb::JOINT_TYPE_UNSPECIFIED);
}

TEST(Convert, OptionsOverrideOnlyWhatIsSet) {
  SlamOptions options;
  options.num_features = 777;
  pb::SlamOptions in;
  in.set_num_levels(3);
  in.set_mapping_mode(pb::MAPPING_MODE_BACKGROUND);
  ASSERT_TRUE(ApplyOptions(in, &options).ok());
  EXPECT_EQ(options.num_features, 777);
  EXPECT_EQ(options.num_levels, 3);
  EXPECT_EQ(options.mapping_mode, MappingMode::kBackground);
  in.set_scale_factor(std::numeric_limits<double>::infinity());
  EXPECT_TRUE(absl::IsInvalidArgument(ApplyOptions(in, &options)));
  pb::SlamOptions out;
  ToProto(options, &out);
  EXPECT_EQ(out.num_levels(), 3);
  EXPECT_EQ(out.object_ba_window_frames(), options.object_ba_window_frames);

  // The objects' BA and parked-instance switches travel too (range checks
  // are the engine's, when the session is created).
  pb::SlamOptions objects;
  objects.set_object_ba_window_frames(0);
  objects.set_object_ba_iterations(4);
  objects.set_parked_objects_static(false);   // the default is true
  objects.set_dense_keyframes(false);         // the default is true
  objects.set_extra_camera_keypoints(false);  // the default is true
  objects.set_stereo_by_point_depth(true);    // the default is false
  objects.set_disparity_offset_px(0.09);      // the default is 0
  SlamOptions o2;
  ASSERT_TRUE(ApplyOptions(objects, &o2).ok());
  EXPECT_EQ(o2.disparity_offset_px, 0.09);
  pb::SlamOptions back;
  ToProto(o2, &back);
  EXPECT_EQ(back.disparity_offset_px(), 0.09);
  pb::SlamOptions not_finite = objects;
  not_finite.set_disparity_offset_px(std::numeric_limits<double>::infinity());
  SlamOptions o3;
  EXPECT_THAT(std::string(ApplyOptions(not_finite, &o3).message()),
              HasSubstr("disparity_offset_px is not finite"));
  EXPECT_FALSE(o2.dense_keyframes);
  EXPECT_FALSE(o2.extra_camera_keypoints);
  EXPECT_TRUE(o2.stereo_by_point_depth);
  EXPECT_EQ(o2.object_ba_window_frames, 0);
  EXPECT_EQ(o2.object_ba_iterations, 4);
  EXPECT_FALSE(o2.parked_objects_static);
  EXPECT_EQ(o2.num_features, SlamOptions().num_features);
}

TEST(Convert, CalibrationValidation) {
  pb::StereoCalibration c = twist::testing::MakeCreateRequest(kW, kH).config().calibration();
  ASSERT_TRUE(RectifiedCameraFromProto(c).ok());
  c.set_baseline(0);
  EXPECT_THAT(std::string(RectifiedCameraFromProto(c).status().message()), HasSubstr("baseline"));
  c.set_baseline(0.5);
  c.set_cx(kW + 5);
  EXPECT_THAT(std::string(RectifiedCameraFromProto(c).status().message()),
              HasSubstr("principal point"));
  c.set_cx(10);
  c.set_width(0);
  EXPECT_TRUE(absl::IsInvalidArgument(RectifiedCameraFromProto(c).status()));
}

TEST(Convert, FrameResultToUpdate) {
  FrameResult r;
  r.index = 4;
  r.timestamp_ns = 99;
  r.state = TrackingState::kOk;
  r.world_from_camera = geometry::SE3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(1, 2, 3));
  r.is_keyframe = true;
  ObjectResult o;
  o.id = 5;
  o.class_id = 26;
  o.instance_id = 2;
  o.state = ObjectState::kTracked;
  o.joint = "planar";
  o.speed_mps = 3.5;
  o.twist_in_world << 1, 2, 3, 4, 5, 6;
  r.objects.push_back(o);
  ClusterEvent e;
  e.type = ClusterEventType::kPlaneUpdated;
  e.cluster_id = 9;
  e.plane = Eigen::Vector4d(0, 1, 0, -1.5);
  r.cluster_events.push_back(e);
  r.timings.push_back({"track", 1.5});
  pb::FrameUpdate u;
  ToProto(r, &u);
  EXPECT_EQ(u.index(), 4);
  EXPECT_EQ(u.tracking_state(), pb::TRACKING_STATE_OK);
  EXPECT_EQ(u.world_from_camera().translation().z(), 3);
  EXPECT_EQ(u.world_from_camera().rotation().w(), 1);
  ASSERT_EQ(u.objects_size(), 1);
  EXPECT_EQ(u.objects(0).joint_type(), pb::JOINT_TYPE_PLANAR);
  EXPECT_EQ(u.objects(0).state(), pb::OBJECT_STATE_TRACKED);
  EXPECT_EQ(u.objects(0).twist_in_world().angular().x(), 4);
  ASSERT_EQ(u.cluster_events_size(), 1);
  EXPECT_EQ(u.cluster_events(0).type(), pb::CLUSTER_EVENT_TYPE_PLANE_UPDATED);
  EXPECT_EQ(u.cluster_events(0).plane().d(), -1.5);
  EXPECT_EQ(u.timings(0).stage(), "track");
}

TEST(Convert, MapChunksRespectTheBudgetAndKeepEverything) {
  MapSnapshot map;
  for (int i = 0; i < 20000; ++i) {
    MapSnapshot::Point p;
    p.p_in_world = Eigen::Vector3d(i, -i, 0.5 * i);
    p.class_id = i % 30;
    p.cluster_id = i % 7 - 1;
    map.points.push_back(p);
  }
  for (int i = 0; i < 50; ++i) map.keyframes.push_back({i, i * 100, geometry::SE3d()});
  MapSnapshot::Cluster c;
  c.id = 3;
  c.is_dynamic = true;
  for (int i = 0; i < 100; ++i) c.trajectory.emplace_back(i, geometry::SE3d());
  map.clusters.push_back(c);
  MapChunkOptions options;
  options.max_chunk_bytes = 64 << 10;
  options.frames_processed = 17;
  const std::vector<pb::MapChunk> chunks = MapToChunks(map, options);
  ASSERT_GT(chunks.size(), 5u);
  int64_t points = 0, keyframes = 0, clusters = 0;
  for (size_t i = 0; i < chunks.size(); ++i) {
    EXPECT_EQ(chunks[i].sequence(), static_cast<int64_t>(i));
    EXPECT_EQ(chunks[i].last(), i + 1 == chunks.size());
    EXPECT_LE(chunks[i].ByteSizeLong(), static_cast<size_t>(options.max_chunk_bytes) + 64);
    points += chunks[i].points_size();
    keyframes += chunks[i].keyframes_size();
    clusters += chunks[i].clusters_size();
  }
  EXPECT_EQ(points, 20000);
  EXPECT_EQ(keyframes, 50);
  EXPECT_EQ(clusters, 1);
  EXPECT_EQ(chunks[0].summary().num_points(), 20000);
  EXPECT_EQ(chunks[0].summary().frames_processed(), 17);
  EXPECT_EQ(chunks[0].summary().num_chunks(), static_cast<int64_t>(chunks.size()));

  options.skip_points = true;
  options.skip_trajectories = true;
  const std::vector<pb::MapChunk> small = MapToChunks(map, options);
  ASSERT_EQ(small.size(), 1u);
  EXPECT_EQ(small[0].clusters(0).trajectory_size(), 0);
}

TEST(Convert, StatusMappingKeepsCodeAndMessage) {
  const grpc::Status g = ToGrpcStatus(absl::NotFoundError("session 'x' not found"));
  EXPECT_EQ(g.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_EQ(g.error_message(), "session 'x' not found");
  EXPECT_TRUE(ToGrpcStatus(absl::OkStatus()).ok());
  EXPECT_EQ(ToGrpcStatus(absl::FailedPreconditionError("x")).error_code(),
            grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_TRUE(absl::IsResourceExhausted(
      FromGrpcStatus(grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED, "m"))));
}

TEST(Rectifier, IdentityRigKeepsImagesAndBaseline) {
  RawStereoRig rig;
  rig.width = kW;
  rig.height = kH;
  rig.left = {100, 100, kW / 2.0, kH / 2.0, {}};
  rig.right = rig.left;
  rig.right_from_left = geometry::SE3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(-0.5, 0, 0));
  absl::StatusOr<StereoRectifier> r = StereoRectifier::Create(rig);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_NEAR(r->rectified_camera().baseline, 0.5, 1e-9);
  EXPECT_NEAR(r->rectified_camera().fx, 100, 1e-6);
  StereoFrame frame;
  frame.left = twist::testing::TestImage(kW, kH, 3, 0);
  frame.right = frame.left.clone();
  frame.panoptic = twist::testing::TestMask(kW, kH);
  const cv::Mat mask_before = frame.panoptic.clone();
  const cv::Mat before = frame.left.clone();
  frame.boxes.push_back({26, 1, 10, 10, 20, 20});
  r->Rectify(&frame);
  EXPECT_LE(cv::norm(frame.left(cv::Rect(2, 2, kW - 4, kH - 4)),
                     before(cv::Rect(2, 2, kW - 4, kH - 4)),
                     cv::NORM_INF),
            1.0);
  EXPECT_EQ(cv::norm(frame.panoptic, mask_before, cv::NORM_INF), 0.0);
  EXPECT_NEAR(frame.boxes[0].x_min, 10, 1e-3);
  EXPECT_NEAR(frame.boxes[0].y_max, 20, 1e-3);
}

TEST(Rectifier, RejectsDegenerateRigs) {
  RawStereoRig rig;
  rig.width = kW;
  rig.height = kH;
  rig.left = {100, 100, kW / 2.0, kH / 2.0, {0.1, 0.01}};  // 2 coefficients: invalid
  rig.right = {100, 100, kW / 2.0, kH / 2.0, {}};
  rig.right_from_left = geometry::SE3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(-0.5, 0, 0));
  EXPECT_THAT(std::string(StereoRectifier::Create(rig).status().message()),
              HasSubstr("distortion"));
  rig.left.distortion = {-0.1, 0.01, 0, 0, 0};
  rig.right_from_left = geometry::SE3d();
  EXPECT_THAT(std::string(StereoRectifier::Create(rig).status().message()), HasSubstr("baseline"));
  rig.right_from_left =
      geometry::SE3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.02, Eigen::Vector3d::UnitY())),
                     Eigen::Vector3d(-0.5, 0.01, 0));
  absl::StatusOr<StereoRectifier> r = StereoRectifier::Create(rig);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_NEAR(r->rectified_camera().baseline, std::sqrt(0.25 + 0.0001), 1e-6);
}

}  // namespace
}  // namespace twist::server
