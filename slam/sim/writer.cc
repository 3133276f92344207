#include "slam/sim/writer.h"

#include <glog/logging.h>
#include <stdlib.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "slam/common/timer.h"
#include "slam/joints/class_table.h"
#include "slam/sim/labels.h"
#include "slam/sim/procedural.h"

namespace twist::sim {
namespace {

namespace fs = std::filesystem;

std::string Row(const Eigen::Matrix<double, 3, 4>& m) {
  std::string out;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 4; ++c) {
      absl::StrAppend(&out, out.empty() ? "" : " ", absl::StrFormat("%.12e", m(r, c)));
    }
  }
  return out;
}

absl::Status WriteText(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
  out.close();
  if (!out) return absl::InternalError(absl::StrCat("cannot write ", path.string()));
  return absl::OkStatus();
}

absl::Status WritePng(const fs::path& path, const cv::Mat& image, int compression) {
  bool ok = false;
  try {
    ok = cv::imwrite(path.string(), image, {cv::IMWRITE_PNG_COMPRESSION, compression});
  } catch (const cv::Exception& e) {
    return absl::InternalError(absl::StrCat("cannot write ", path.string(), ": ", e.what()));
  }
  if (!ok) return absl::InternalError(absl::StrCat("cannot write ", path.string()));
  return absl::OkStatus();
}

absl::Status MakeDirs(const fs::path& dir) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec)
    return absl::InternalError(absl::StrCat("cannot create ", dir.string(), ": ", ec.message()));
  return absl::OkStatus();
}

// The items of one sequence, relative to the dataset root. Data first,
// calibration last: a reader needs the calibration, so an interrupted move
// never looks like a complete sequence.
std::vector<fs::path> SequenceItems(const std::string& seq) {
  return {fs::path("image_02") / seq,
          fs::path("image_03") / seq,
          fs::path("panoptic") / seq,
          fs::path("label_02") / (seq + ".txt"),
          fs::path("objects_gt") / (seq + ".txt"),
          fs::path("poses") / (seq + ".txt"),
          fs::path("times") / (seq + ".txt"),
          fs::path("calib") / (seq + ".txt")};
}

absl::Status WriteAll(const Scenario& sc,
                      const fs::path& root,
                      const WriteOptions& options,
                      const std::function<void(int, int)>& progress,
                      WriteStats* stats) {
  const std::string& seq = options.sequence;
  for (const char* d : {"image_02", "image_03", "panoptic"}) {
    if (auto st = MakeDirs(root / d / seq); !st.ok()) return st;
  }
  for (const char* d : {"calib", "poses", "times", "label_02", "objects_gt"}) {
    if (auto st = MakeDirs(root / d); !st.ok()) return st;
  }
  const Renderer renderer(sc.camera, options.render);
  std::string poses, times, labels, objects;
  std::vector<double> render_ms;
  RenderScratch scratch;
  StereoRender frame;
  for (int i = 0; i < sc.num_frames; ++i) {
    if (options.cancel != nullptr && options.cancel->load()) {
      return absl::CancelledError(
          absl::StrCat("cancelled after ", i, " of ", sc.num_frames, " frames"));
    }
    const geometry::SE3d world_from_camera = sc.WorldFromCamera(i);
    Exposure left, right;
    FrameExposures(sc, i, &left, &right);
    Stopwatch watch;
    renderer.RenderStereo(sc.scene, sc.TimeOf(i), world_from_camera, left, right, &scratch, &frame);
    render_ms.push_back(watch.ElapsedMs());
    const std::string name = absl::StrFormat("%06d.png", i);
    if (auto st = WritePng(root / "image_02" / seq / name, frame.left, options.png_compression);
        !st.ok())
      return st;
    if (auto st = WritePng(root / "image_03" / seq / name, frame.right, options.png_compression);
        !st.ok())
      return st;
    if (auto st = WritePng(root / "panoptic" / seq / name, frame.panoptic, options.png_compression);
        !st.ok())
      return st;
    for (const FrameLabel& label : ComputeFrameLabels(sc, renderer, i, frame.panoptic)) {
      absl::StrAppend(&labels, FormatKittiLabel(i, label), "\n");
      absl::StrAppend(&objects, FormatObjectGt(i, label), "\n");
    }
    absl::StrAppend(&poses, Row(world_from_camera.matrix3x4()), "\n");
    absl::StrAppend(&times, absl::StrFormat("%.6e", sc.TimeOf(i)), "\n");
    if (progress) progress(i + 1, sc.num_frames);
  }
  if (auto st = WriteText(root / "label_02" / (seq + ".txt"), labels); !st.ok()) return st;
  if (auto st = WriteText(root / "objects_gt" / (seq + ".txt"), objects); !st.ok()) return st;
  if (auto st = WriteText(root / "poses" / (seq + ".txt"), poses); !st.ok()) return st;
  if (auto st = WriteText(root / "times" / (seq + ".txt"), times); !st.ok()) return st;
  if (auto st = WriteText(root / "calib" / (seq + ".txt"), CalibrationText(sc.camera)); !st.ok())
    return st;
  if (auto st = WriteText(root / "classes.txt", ClassTableText()); !st.ok()) return st;
  if (stats != nullptr) {
    std::sort(render_ms.begin(), render_ms.end());
    stats->render_ms_median = render_ms.empty() ? 0.0 : render_ms[render_ms.size() / 2];
  }
  return absl::OkStatus();
}

}  // namespace

void FrameExposures(const Scenario& scenario, int frame, Exposure* left, Exposure* right) {
  const uint32_t base = procedural::Hash(scenario.seed * 0x9e3779b1U + 0x51u);
  // Slow auto-exposure drift shared by both cameras, and a fixed right/left
  // difference of up to ±3 % gain and ±3 grey levels.
  const double drift = 0.03 * std::sin(0.37 * frame + procedural::Unit(base) * 6.28);
  const double right_gain = 1.0 + 0.06 * (procedural::Unit(procedural::Hash(base + 1u)) - 0.5);
  const double right_offset = 6.0 * (procedural::Unit(procedural::Hash(base + 2u)) - 0.5);
  left->gain = 1.0 + drift;
  left->offset = 0.0;
  left->noise_seed = procedural::Hash(base ^ (static_cast<uint32_t>(frame) * 2u + 0u));
  right->gain = (1.0 + drift) * right_gain;
  right->offset = right_offset;
  right->noise_seed = procedural::Hash(base ^ (static_cast<uint32_t>(frame) * 2u + 1u));
}

std::string CalibrationText(const geometry::StereoCamera& camera) {
  const Eigen::Matrix<double, 3, 4> p_left = camera.LeftProjectionMatrix();
  const Eigen::Matrix<double, 3, 4> p_right = camera.RightProjectionMatrix();
  // Velodyne (x forward, y left, z up) 1 m behind and 0.08 m above the camera,
  // IMU 0.8 m behind the Velodyne; nominal values, no sensor data is written.
  Eigen::Matrix<double, 3, 4> velo;
  velo << 0, -1, 0, 0, 0, 0, -1, -0.08, 1, 0, 0, -0.27;
  Eigen::Matrix<double, 3, 4> imu;
  imu << 1, 0, 0, -0.81, 0, 1, 0, 0.32, 0, 0, 1, -0.8;
  std::string r_rect;
  for (int i = 0; i < 9; ++i) {
    absl::StrAppend(&r_rect, i == 0 ? "" : " ", absl::StrFormat("%.12e", i % 4 == 0 ? 1.0 : 0.0));
  }
  return absl::StrCat("P0: ",
                      Row(p_left),
                      "\n",
                      "P1: ",
                      Row(p_right),
                      "\n",
                      "P2: ",
                      Row(p_left),
                      "\n",
                      "P3: ",
                      Row(p_right),
                      "\n",
                      "R_rect: ",
                      r_rect,
                      "\n",
                      "Tr_velo_cam: ",
                      Row(velo),
                      "\n",
                      "Tr_imu_velo: ",
                      Row(imu),
                      "\n");
}

std::string ClassTableText() {
  using joints::ClassInfo;
  using joints::JointType;
  std::vector<ClassInfo> classes;
  auto add = [&](int id, const char* name, bool plane) {
    ClassInfo c;
    c.id = id;
    c.name = name;
    c.fit_plane = plane;
    classes.push_back(c);
  };
  auto add_dynamic = [&](int id, const char* name, int parent, JointType joint) {
    ClassInfo c;
    c.id = id;
    c.name = name;
    c.is_dynamic = true;
    c.parent_id = parent;
    c.joint = joint;
    classes.push_back(c);
  };
  add(kClassRoad, "road", true);
  add(kClassSidewalk, "sidewalk", true);
  add(kClassBuilding, "building", true);
  add(kClassWall, "wall", true);
  add(kClassPole, "pole", false);
  add(kClassVegetation, "vegetation", false);
  add(kClassSky, "sky", false);
  add_dynamic(kClassPerson, "person", kClassRoad, JointType::kPlanar);
  add_dynamic(kClassCar, "car", kClassRoad, JointType::kPlanar);
  add_dynamic(kClassDoor, "door", kClassWall, JointType::kRevolute);
  absl::StatusOr<joints::ClassTable> table = joints::ClassTable::Create(std::move(classes));
  CHECK(table.ok()) << table.status();
  return table->ToText();
}

absl::Status WriteSequence(const Scenario& scenario,
                           const std::string& out_dir,
                           const WriteOptions& options,
                           const std::function<void(int, int)>& progress,
                           WriteStats* stats) {
  if (options.sequence.empty() || options.sequence.find('/') != std::string::npos) {
    return absl::InvalidArgumentError(absl::StrCat("bad sequence name '", options.sequence, "'"));
  }
  Stopwatch total;
  std::error_code ec;
  fs::path out = fs::path(out_dir).lexically_normal();
  if (out.filename().empty()) out = out.parent_path();  // "DIR/" -> "DIR"
  if (out.empty()) return absl::InvalidArgumentError("empty output directory");
  const bool exists = fs::exists(out, ec);
  if (exists && !fs::is_directory(out, ec)) {
    return absl::InvalidArgumentError(absl::StrCat(out_dir, " exists and is not a directory"));
  }
  const bool merge = exists && !fs::is_empty(out, ec);
  if (merge) {
    for (const fs::path& item : SequenceItems(options.sequence)) {
      if (fs::exists(out / item, ec)) {
        return absl::AlreadyExistsError(absl::StrCat(
            out_dir, " already has sequence ", options.sequence, " (", item.string(), ")"));
      }
    }
  }
  // Temporary directory: inside the dataset when merging, next to it otherwise.
  fs::path parent = merge ? out : out.parent_path();
  if (parent.empty()) parent = ".";
  if (auto st = MakeDirs(parent); !st.ok()) return st;
  std::string pattern =
      (parent / ((merge ? std::string(".") : out.filename().string()) + ".tmp-XXXXXX")).string();
  std::vector<char> buf(pattern.begin(), pattern.end());
  buf.push_back('\0');
  if (mkdtemp(buf.data()) == nullptr) {
    return absl::InternalError(
        absl::StrCat("cannot create a temporary directory in ", parent.string()));
  }
  const fs::path tmp(buf.data());
  absl::Status status = WriteAll(scenario, tmp, options, progress, stats);
  if (status.ok()) {
    if (merge) {
      for (const fs::path& item : SequenceItems(options.sequence)) {
        MakeDirs((out / item).parent_path()).IgnoreError();
        fs::rename(tmp / item, out / item, ec);
        if (ec) {
          status = absl::InternalError(
              absl::StrCat("cannot move ", item.string(), " into ", out_dir, ": ", ec.message()));
          break;
        }
      }
      if (status.ok() && !fs::exists(out / "classes.txt", ec)) {
        fs::rename(tmp / "classes.txt", out / "classes.txt", ec);
      }
    } else {
      if (exists) fs::remove(out, ec);  // empty directory
      fs::rename(tmp, out, ec);
      if (ec) {
        status = absl::InternalError(
            absl::StrCat("cannot rename ", tmp.string(), " to ", out_dir, ": ", ec.message()));
      }
    }
  }
  fs::remove_all(tmp, ec);
  if (stats != nullptr) stats->total_ms = total.ElapsedMs();
  return status;
}

}  // namespace twist::sim
