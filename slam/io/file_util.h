// Text-file helpers shared by the dataset readers and writers: whole-file
// reads with clear errors, line splitting with 1-based line numbers, strict
// number parsing, and atomic writes (temp file + rename).
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace twist::io {

// Reads a whole file. NotFound "<path>: no such file" when it does not exist,
// FailedPrecondition when it is a directory or unreadable.
absl::StatusOr<std::string> ReadTextFile(const std::string& path);

struct TextLine {
  int number = 0;         // 1-based line number in the file
  std::string_view text;  // without the line terminator (\n or \r\n)
};
// Splits `text` into lines; blank (whitespace-only) lines are dropped and lines
// starting with '#' are dropped when `skip_comments` is set.
std::vector<TextLine> SplitLines(std::string_view text, bool skip_comments = false);

// Splits on spaces and tabs.
std::vector<std::string_view> SplitFields(std::string_view text);

// Strict conversions of a whole token; false on any trailing garbage,
// overflow, NaN or infinity.
bool ParseDouble(std::string_view token, double* value);
bool ParseInt64(std::string_view token, int64_t* value);

// Parses a line of exactly `count` numbers (count < 0: any number >= 1).
// InvalidArgument "<path>:<line>: <what>" otherwise.
absl::Status ParseNumberLine(const std::string& path,
                             const TextLine& line,
                             int count,
                             std::vector<double>* values);

// "<path>:<line>: <message>" as InvalidArgument.
absl::Status LineError(const std::string& path, int line, const std::string& message);

// Writes `contents` to `path` via a mkstemp "<path>.tmp.XXXXXX" renamed over `path`, so
// a reader never sees a partially written file. Creates no directories.
absl::Status WriteFileAtomic(const std::string& path, const std::string& contents);

bool FileExists(const std::string& path);
bool DirExists(const std::string& path);
std::string JoinPath(const std::string& a, const std::string& b);

// Shortest decimal text that reads back as the same double (%.17g, trimmed
// to %.Ng for the smallest N that round-trips).
std::string FormatDouble(double value);

}  // namespace twist::io
