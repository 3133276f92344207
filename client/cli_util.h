// Small helpers shared by the `twistslam` sub-commands: `--key value`
// argument parsing, one-line error reporting and atomic file output.
// Standard library only, so any command can use them whatever it links.
#pragma once

#include <cstdint>
#include <fstream>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

namespace twist::cli {

// Parsed `--key value` / `--flag` arguments of one sub-command.
//
//   ArgParser parser("eval");
//   parser.AddValue("dataset", "DIR", "dataset root");
//   parser.AddValue("json", "FILE", "also write the metrics as JSON", /*required=*/false);
//   parser.AddFlag("verbose", "print per-frame errors");
//   std::optional<Args> args = parser.Parse(argc, argv);   // argv[0] = command name
//   if (!args) return parser.exit_code();                  // error/usage already printed
class Args {
 public:
  bool Has(const std::string& key) const { return values_.count(key) > 0; }
  bool Flag(const std::string& key) const { return flags_.count(key) > 0; }
  // Value of `key`, or `fallback` when absent.
  std::string Get(const std::string& key, const std::string& fallback = "") const;
  // Typed getters: nullopt when the value is present but does not parse
  // entirely as the type (the caller reports it with Fail). Absent keys give
  // `fallback`.
  std::optional<int64_t> GetInt(const std::string& key, int64_t fallback) const;
  std::optional<double> GetDouble(const std::string& key, double fallback) const;

  std::map<std::string, std::string> values_;
  std::set<std::string> flags_;
};

class ArgParser {
 public:
  explicit ArgParser(std::string command) : command_(std::move(command)) {}

  // A key that takes one value (`--key value` or `--key=value`).
  ArgParser& AddValue(const std::string& key,
                      const std::string& metavar,
                      const std::string& help,
                      bool required = true,
                      const std::string& default_text = "");
  // A boolean switch without value.
  ArgParser& AddFlag(const std::string& key, const std::string& help);

  // Parses argv[1..argc) (argv[0] is the command name). On `--help` prints the
  // usage to stdout and returns nullopt with exit_code() 0; on an unknown key,
  // a missing value or a missing required key prints one line
  // "twistslam <command>: <reason>" to stderr and returns nullopt with
  // exit_code() 2.
  std::optional<Args> Parse(int argc, char** argv);
  int exit_code() const { return exit_code_; }
  std::string Usage() const;

 private:
  struct Option {
    std::string key, metavar, help, default_text;
    bool takes_value = true;
    bool required = false;
  };
  const Option* Find(const std::string& key) const;

  std::string command_;
  std::vector<Option> options_;
  int exit_code_ = 0;
};

// Prints "twistslam <command>: <message>" on one line (newlines in the message
// become "; ") to stderr and returns `exit_code`.
int Fail(const std::string& command, const std::string& message, int exit_code = 1);

// Collapses a multi-line message to a single line.
std::string OneLine(const std::string& message);

// Writes `contents` to `path` through a temporary file in the same directory
// that is renamed over `path` at the end, so readers never see a partial file.
// Returns false and fills *error ("cannot write <path>: <reason>") on failure;
// the temporary is removed.
bool WriteFileAtomic(const std::string& path, const std::string& contents, std::string* error);

// Streaming variant: write to stream(), then Commit() renames into place.
// Destroying an uncommitted AtomicFile deletes the temporary.
class AtomicFile {
 public:
  explicit AtomicFile(std::string path);
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  bool ok() const { return stream_.is_open() && stream_.good(); }
  std::ofstream& stream() { return stream_; }
  const std::string& temp_path() const { return temp_path_; }
  bool Commit(std::string* error);

 private:
  std::string path_;
  std::string temp_path_;
  std::ofstream stream_;
  bool committed_ = false;
};

// Creates `dir` and its parents if needed. False + *error on failure.
bool MakeDirs(const std::string& dir, std::string* error);

}  // namespace twist::cli
