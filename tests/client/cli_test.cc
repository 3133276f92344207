// The installed executables as a user runs them: twistslam-server (first
// stdout line, SIGTERM) and `twistslam run` over it and embedded (same
// camera poses, every output file), `twistslam map`, and one-line errors.
#include <fcntl.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "slam/sim/scenarios.h"
#include "slam/sim/writer.h"

namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using ::testing::Not;

std::string ReadAll(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// Runs a shell command; returns its exit code and stderr.
int Shell(const std::string& command, std::string* err = nullptr) {
  const std::string err_file = ::testing::TempDir() + "/twist_cli_stderr.txt";
  const int rc = std::system((command + " 2>" + err_file).c_str());
  if (err) *err = ReadAll(err_file);
  return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

class Server {
 public:
  explicit Server(const std::vector<std::string>& extra) {
    int out[2];
    EXPECT_EQ(pipe(out), 0);
    pid_ = fork();
    if (pid_ == 0) {
      dup2(out[1], 1);
      close(out[0]);
      const int devnull = open("/dev/null", O_WRONLY);
      dup2(devnull, 2);
      std::vector<std::string> args = {TWISTSLAM_SERVER_BIN, "--listen", "127.0.0.1:0"};
      args.insert(args.end(), extra.begin(), extra.end());
      std::vector<char*> argv;
      for (auto& a : args) argv.push_back(a.data());
      argv.push_back(nullptr);
      execv(argv[0], argv.data());
      _exit(127);
    }
    close(out[1]);
    FILE* f = fdopen(out[0], "r");
    char line[256] = {0};
    if (fgets(line, sizeof(line), f) != nullptr) first_line_ = line;
    fclose(f);
  }
  ~Server() {
    if (pid_ > 0) Stop();
  }
  // SIGTERM, then wait (bounded) for a clean exit; returns the exit code.
  int Stop() {
    kill(pid_, SIGTERM);
    int status = 0;
    for (int i = 0; i < 600; ++i) {  // up to 60 s: a liveness bound, not a timing
      if (waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
      }
      usleep(100000);
    }
    kill(pid_, SIGKILL);
    waitpid(pid_, &status, 0);
    pid_ = -1;
    return -2;
  }
  const std::string& first_line() const { return first_line_; }
  std::string address() const {
    const std::string prefix = "listening on ";
    if (first_line_.rfind(prefix, 0) != 0) return "";
    std::string a = first_line_.substr(prefix.size());
    while (!a.empty() && (a.back() == '\n' || a.back() == '\r')) a.pop_back();
    return a;
  }

 private:
  pid_t pid_ = -1;
  std::string first_line_;
};

std::string MakeDataset() {
  const std::string dir = ::testing::TempDir() + "/twist_cli_dataset";
  if (fs::exists(dir + "/image_02/0000")) return dir;
  absl::StatusOr<twist::sim::Scenario> scenario = twist::sim::MakeScenario("driving", 5, 6);
  EXPECT_TRUE(scenario.ok());
  auto& cam = scenario->camera;
  cam.fx *= 0.4;
  cam.fy *= 0.4;
  cam.cx *= 0.4;
  cam.cy *= 0.4;
  cam.width = static_cast<int>(cam.width * 0.4);
  cam.height = static_cast<int>(cam.height * 0.4);
  twist::sim::WriteOptions options;
  options.render.gray = true;
  EXPECT_TRUE(twist::sim::WriteSequence(*scenario, dir, options).ok());
  return dir;
}

TEST(Cli, ServerRunAndMapEndToEnd) {
  const std::string dataset = MakeDataset();
  const std::string state = ::testing::TempDir() + "/twist_cli_state";
  fs::remove_all(state);
  Server server({"--state-dir", state});
  ASSERT_THAT(server.first_line(),
              ::testing::MatchesRegex("listening on 127\\.0\\.0\\.1:[0-9]+\n"));
  const std::string out_remote = ::testing::TempDir() + "/twist_cli_remote";
  const std::string out_local = ::testing::TempDir() + "/twist_cli_local";
  fs::remove_all(out_remote);
  fs::remove_all(out_local);
  const std::string common = std::string(TWISTSLAM_BIN) + " run --dataset " + dataset +
                             " --format kitti-tracking --seq 0000 ";
  // The server maps in the session's thread unless told otherwise; the
  // comparison with the embedded engine asks for its deterministic mode.
  const std::string sync_config = ::testing::TempDir() + "/twist_cli_sync.yaml";
  {
    std::ofstream f(sync_config);
    f << "slam:\n  mapping_mode: synchronous\n";
  }
  std::string err;
  ASSERT_EQ(
      Shell(common + "--out " + out_remote + " --server " + server.address() + " --config " +
                sync_config + " --keep-session > " + ::testing::TempDir() + "/twist_cli_stdout.txt",
            &err),
      0)
      << err;
  EXPECT_THAT(err, HasSubstr("frames/s"));
  EXPECT_THAT(ReadAll(out_remote + "/summary.json"),
              HasSubstr("\"mapping_mode\": \"synchronous\""));
  // No --config: the server's default, mapping in the background.
  const std::string out_default = ::testing::TempDir() + "/twist_cli_remote_default";
  fs::remove_all(out_default);
  ASSERT_EQ(Shell(common + "--out " + out_default + " --server " + server.address(), &err), 0)
      << err;
  EXPECT_THAT(ReadAll(out_default + "/summary.json"),
              HasSubstr("\"mapping_mode\": \"background\""));
  const std::string default_updates = ReadAll(out_default + "/updates.jsonl");
  EXPECT_EQ(std::count(default_updates.begin(), default_updates.end(), '\n'), 6);
  ASSERT_EQ(Shell(common + "--out " + out_local + " --embedded", &err), 0) << err;
  EXPECT_THAT(ReadAll(out_local + "/summary.json"), HasSubstr("\"mapping_mode\": \"synchronous\""));
  // Quiet by default; GLOG_v=1 shows the engine's verbose log (the tracker's
  // per-frame line).
  EXPECT_THAT(err, ::testing::Not(HasSubstr(" path ")));
  const std::string out_verbose = ::testing::TempDir() + "/twist_cli_verbose";
  fs::remove_all(out_verbose);
  ASSERT_EQ(Shell("GLOG_v=1 " + common + "--out " + out_verbose + " --embedded", &err), 0) << err;
  EXPECT_THAT(err, HasSubstr("frame 1 path "));
  for (const char* file : {"camera.txt",
                           "camera_tum.txt",
                           "objects.txt",
                           "objects_refined.txt",
                           "summary.json",
                           "updates.jsonl",
                           "map.ply"}) {
    EXPECT_TRUE(fs::exists(out_remote + "/" + file)) << file;
    EXPECT_TRUE(fs::exists(out_local + "/" + file)) << file;
  }
  // The server and the embedded engine give the same trajectory.
  EXPECT_EQ(ReadAll(out_remote + "/camera.txt"), ReadAll(out_local + "/camera.txt"));
  EXPECT_EQ(ReadAll(out_remote + "/objects.txt"), ReadAll(out_local + "/objects.txt"));
  // The refined trajectories come through GetMap the same as from the
  // embedded engine's snapshot.
  const std::string refined = ReadAll(out_remote + "/objects_refined.txt");
  EXPECT_EQ(refined, ReadAll(out_local + "/objects_refined.txt"));
  const std::string online = ReadAll(out_remote + "/objects.txt");
  EXPECT_GT(std::count(online.begin(), online.end(), '\n'), 0);
  EXPECT_EQ(std::count(refined.begin(), refined.end(), '\n'),
            std::count(online.begin(), online.end(), '\n'));
  const std::string updates = ReadAll(out_remote + "/updates.jsonl");
  EXPECT_EQ(std::count(updates.begin(), updates.end(), '\n'), 6);
  EXPECT_THAT(ReadAll(out_remote + "/summary.json"), HasSubstr("\"mode\": \"server"));

  // `twistslam map` on the kept session.
  std::istringstream kept(ReadAll(::testing::TempDir() + "/twist_cli_stdout.txt"));
  std::string word, session;
  kept >> word >> session;
  ASSERT_EQ(word, "session");
  const std::string ply = ::testing::TempDir() + "/twist_cli_map.ply";
  ASSERT_EQ(Shell(std::string(TWISTSLAM_BIN) + " map --server " + server.address() + " --session " +
                      session + " --out " + ply,
                  &err),
            0)
      << err;
  EXPECT_THAT(ReadAll(ply), HasSubstr("end_header"));
  EXPECT_EQ(Shell(std::string(TWISTSLAM_BIN) + " map --server " + server.address() +
                      " --session nope --out " + ply + ".2",
                  &err),
            1);
  EXPECT_THAT(err, HasSubstr("not found"));
  EXPECT_FALSE(fs::exists(ply + ".2"));

  EXPECT_EQ(server.Stop(), 0);
  // Shutdown persisted the kept session.
  EXPECT_TRUE(fs::exists(state + "/" + session + "/CURRENT"));
  fs::remove_all(state);
}

// `twistslam calibrate` on a generated sequence (the renderer's rig has no
// disparity offset): the offset and the config line; one-line errors.
TEST(Cli, CalibrateMeasuresTheRigsDisparityOffset) {
  const std::string out_file = ::testing::TempDir() + "/twist_cli_calibrate.txt";
  std::string err;
  ASSERT_EQ(Shell(std::string(TWISTSLAM_BIN) + " calibrate --dataset " + MakeDataset() +
                      " --format kitti-tracking --seq 0000 >" + out_file,
                  &err),
            0)
      << err;
  const std::string out = ReadAll(out_file);
  EXPECT_THAT(out, HasSubstr("disparity offset "));
  EXPECT_THAT(out, HasSubstr("slam:\n  disparity_offset_px: "));
  const size_t at = out.find("disparity_offset_px: ");
  ASSERT_NE(at, std::string::npos);
  EXPECT_LT(std::abs(std::stod(out.substr(at + 21))), 0.1) << out;
  // Metric poses from elsewhere (--poses): the same motion, the same offset;
  // a file that does not have one pose per frame is refused.
  const std::string gt_poses = MakeDataset() + "/poses/0000.txt";
  ASSERT_EQ(Shell(std::string(TWISTSLAM_BIN) + " calibrate --dataset " + MakeDataset() +
                      " --format kitti-tracking --seq 0000 --poses " + gt_poses + " >" + out_file,
                  &err),
            0)
      << err;
  const std::string given = ReadAll(out_file);
  EXPECT_THAT(given, HasSubstr("agree with the given motion"));
  EXPECT_EQ(given.substr(given.find("disparity offset ")),
            out.substr(out.find("disparity offset ")));
  const std::string short_poses = ::testing::TempDir() + "/twist_cli_short_poses.txt";
  {
    std::ofstream f(short_poses);
    f << "1 0 0 0 0 1 0 0 0 0 1 0\n";
  }
  EXPECT_EQ(Shell(std::string(TWISTSLAM_BIN) + " calibrate --dataset " + MakeDataset() +
                      " --format kitti-tracking --seq 0000 --poses " + short_poses,
                  &err),
            1);
  EXPECT_THAT(err, HasSubstr("has 1 poses, the sequence 6 frames"));
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1);
  EXPECT_EQ(Shell(std::string(TWISTSLAM_BIN) + " calibrate --dataset " + MakeDataset() +
                      " --format kitti-tracking --seq 0000 --poses /nonexistent/poses.txt",
                  &err),
            1);
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1);
  // Too few frames left, a missing dataset, a bad format: one line each.
  EXPECT_EQ(Shell(std::string(TWISTSLAM_BIN) + " calibrate --dataset " + MakeDataset() +
                      " --format kitti-tracking --seq 0000 --first 5",
                  &err),
            2);
  EXPECT_THAT(err, HasSubstr("fewer than 2"));
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1);
  EXPECT_EQ(Shell(std::string(TWISTSLAM_BIN) +
                      " calibrate --dataset /nonexistent --format kitti-odometry --seq 00",
                  &err),
            1);
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1);
  EXPECT_EQ(
      Shell(std::string(TWISTSLAM_BIN) + " calibrate --dataset /x --format bogus --seq 00", &err),
      2);
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1);
}

// A frame whose image cannot be read mid-sequence is skipped and reported
// (exit 3); the frames before and after it are processed and every output is
// written, embedded and through a server alike.
TEST(Cli, AnUnreadableFrameIsSkippedAndNothingElseIsLost) {
  const std::string dataset = ::testing::TempDir() + "/twist_cli_damaged";
  fs::remove_all(dataset);
  fs::copy(MakeDataset(), dataset, fs::copy_options::recursive);
  {
    std::ofstream f(dataset + "/image_02/0000/000003.png", std::ios::binary | std::ios::trunc);
    f << "not a PNG";
  }
  Server server({});
  ASSERT_FALSE(server.address().empty()) << server.first_line();
  for (const std::string& mode : {std::string("--embedded"), "--server " + server.address()}) {
    const std::string out = ::testing::TempDir() + "/twist_cli_damaged_out";
    fs::remove_all(out);
    std::string err;
    EXPECT_EQ(Shell(std::string(TWISTSLAM_BIN) + " run --dataset " + dataset +
                        " --format kitti-tracking --seq 0000 --out " + out + " " + mode,
                    &err),
              3)
        << mode << ": " << err;
    EXPECT_THAT(err, HasSubstr("frame 3: "));
    EXPECT_THAT(err, HasSubstr("000003.png"));
    EXPECT_THAT(err, HasSubstr("5/6 frames processed (1 errors"));
    const std::string summary = ReadAll(out + "/summary.json");
    EXPECT_THAT(summary, HasSubstr("\"frames_processed\": 5")) << mode;
    EXPECT_THAT(summary, HasSubstr("\"frame_errors\": 1")) << mode;
    const std::string camera = ReadAll(out + "/camera.txt");
    EXPECT_EQ(std::count(camera.begin(), camera.end(), '\n'), 5) << mode;
  }
  EXPECT_EQ(server.Stop(), 0);
  fs::remove_all(dataset);
}

// --realtime paces the frames by their timestamps: 6 frames at 10 Hz take at
// least the 0.5 s between the first and the last (a lower bound only: a slow
// machine takes longer, never shorter).
TEST(Cli, RealtimeSendsEachFrameAtItsTimestamp) {
  const std::string dataset = MakeDataset();
  const std::string out = ::testing::TempDir() + "/twist_cli_realtime";
  fs::remove_all(out);
  std::string err;
  ASSERT_EQ(Shell(std::string(TWISTSLAM_BIN) + " run --embedded --realtime --dataset " + dataset +
                      " --format kitti-tracking --seq 0000 --out " + out,
                  &err),
            0)
      << err;
  const std::string summary = ReadAll(out + "/summary.json");
  EXPECT_THAT(summary, HasSubstr("\"realtime_late_frames\": "));
  EXPECT_THAT(summary, HasSubstr("\"frames_processed\": 6"));
  const size_t at = summary.find("\"wall_time_s\": ");
  ASSERT_NE(at, std::string::npos) << summary;
  EXPECT_GE(std::stod(summary.substr(at + 15)), 0.5);
  // Without the flag the key is absent.
  fs::remove_all(out);
  ASSERT_EQ(Shell(std::string(TWISTSLAM_BIN) + " run --embedded --dataset " + dataset +
                      " --format kitti-tracking --seq 0000 --out " + out,
                  &err),
            0)
      << err;
  EXPECT_THAT(ReadAll(out + "/summary.json"), Not(HasSubstr("realtime_late_frames")));
  fs::remove_all(out);
}

TEST(Cli, BadArgumentsAndInputsFailWithOneLine) {
  std::string err;
  EXPECT_EQ(Shell(std::string(TWISTSLAM_BIN) +
                      " run --dataset /x --format kitti-odometry --seq 00 --out /tmp/x",
                  &err),
            2);
  EXPECT_THAT(err, HasSubstr("exactly one of --server"));
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1);
  const std::string out = ::testing::TempDir() + "/twist_cli_missing";
  fs::remove_all(out);
  EXPECT_EQ(Shell(std::string(TWISTSLAM_BIN) +
                      " run --dataset /nonexistent --format kitti-odometry --seq 00 --out " + out +
                      " --embedded",
                  &err),
            1);
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1);
  EXPECT_FALSE(fs::exists(out + "/summary.json"));
  // No server there: a clear failure, no outputs.
  EXPECT_NE(Shell(std::string(TWISTSLAM_BIN) + " run --dataset " + MakeDataset() +
                      " --format kitti-tracking --seq 0000 --out " + out +
                      " --server 127.0.0.1:1 --token-file /nope",
                  &err),
            0);
  EXPECT_THAT(err, HasSubstr("token file"));
  EXPECT_EQ(Shell(std::string(TWISTSLAM_SERVER_BIN) + " --bogus 1", &err), 2);
  EXPECT_THAT(err, HasSubstr("unknown flag --bogus"));
  EXPECT_EQ(Shell(std::string(TWISTSLAM_SERVER_BIN) + " --auth-token-file /nonexistent", &err), 1);
  EXPECT_THAT(err, HasSubstr("token file"));
}

}  // namespace
