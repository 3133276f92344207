// Argument handling of `twistslam generate` (client/cmd_generate.cc).
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <string>
#include <vector>

#include "client/commands.h"

namespace twist::cli {
namespace {

namespace fs = std::filesystem;

struct Result {
  int code;
  std::string out, err;
};

Result RunGenerate(std::vector<std::string> args) {
  args.insert(args.begin(), "generate");
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  ::testing::internal::CaptureStdout();
  ::testing::internal::CaptureStderr();
  const int code = GenerateCommand(static_cast<int>(argv.size()), argv.data());
  Result r{
      code, ::testing::internal::GetCapturedStdout(), ::testing::internal::GetCapturedStderr()};
  return r;
}

int Lines(const std::string& s) { return static_cast<int>(std::count(s.begin(), s.end(), '\n')); }

TEST(GenerateCommand, HelpListsTheScenarios) {
  const Result r = RunGenerate({"--help"});
  EXPECT_EQ(r.code, 0);
  for (const char* name : {"static_street",
                           "driving",
                           "intersection",
                           "turning_traffic",
                           "stationary_then_accelerating",
                           "follow_braking",
                           "door"}) {
    EXPECT_NE(r.out.find(name), std::string::npos) << name;
  }
}

TEST(GenerateCommand, BadArgumentsGiveOneLineAndNonZeroExit) {
  const std::string out = (fs::path(::testing::TempDir()) / "twist_gen_bad").string();
  fs::remove_all(out);
  const std::vector<std::vector<std::string>> cases = {
      {"--out", out},                                              // no scenario
      {"--scenario", "driving"},                                   // no output
      {"--scenario", "nope", "--out", out},                        // unknown scenario
      {"--scenario", "driving", "--out", out, "--frames", "0"},    // no frames
      {"--scenario", "driving", "--out", out, "--frames", "ten"},  // not a number
      {"--scenario", "driving", "--out", out, "--seed", "-3"},     // negative seed
      {"--scenario", "driving", "--out", out, "--seq", "a/b"},     // bad sequence name
      {"--scenario", "driving", "--out", out, "--fps", "5"},       // unknown option
      {"--scenario", "driving", "--out", out, "--frames"},         // missing value
  };
  for (const auto& c : cases) {
    const Result r = RunGenerate(c);
    EXPECT_NE(r.code, 0) << c.back();
    EXPECT_EQ(Lines(r.err), 1) << r.err;
    EXPECT_NE(r.err.find("generate"), std::string::npos) << r.err;
  }
  EXPECT_FALSE(fs::exists(out));
}

TEST(GenerateCommand, WritesASequenceAndRefusesToOverwriteIt) {
  const fs::path out = fs::path(::testing::TempDir()) / "twist_gen_ok";
  fs::remove_all(out);
  Result r = RunGenerate(
      {"--scenario", "door", "--out", out.string(), "--frames", "2", "--seq", "0003", "--gray"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(fs::exists(out / "image_03/0003/000001.png"));
  EXPECT_TRUE(fs::exists(out / "objects_gt/0003.txt"));
  r = RunGenerate({"--scenario", "door", "--out", out.string(), "--frames", "2", "--seq", "0003"});
  EXPECT_NE(r.code, 0);
  EXPECT_EQ(Lines(r.err), 1) << r.err;
}

}  // namespace
}  // namespace twist::cli
