#include "slam/io/file_util.h"

#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <system_error>

namespace twist::io {

absl::StatusOr<std::string> ReadTextFile(const std::string& path) {
  std::error_code ec;
  const auto status = std::filesystem::status(path, ec);
  if (ec || !std::filesystem::exists(status)) {
    return absl::NotFoundError(path + ": no such file");
  }
  if (std::filesystem::is_directory(status)) {
    return absl::FailedPreconditionError(path + ": is a directory, expected a file");
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return absl::FailedPreconditionError(path +
                                         ": cannot open for reading: " + std::strerror(errno));
  }
  std::ostringstream buffer;
  buffer << in.rdbuf();
  if (in.bad()) return absl::DataLossError(path + ": read error");
  return buffer.str();
}

std::vector<TextLine> SplitLines(std::string_view text, bool skip_comments) {
  std::vector<TextLine> lines;
  int number = 0;
  size_t start = 0;
  while (start <= text.size()) {
    size_t end = text.find('\n', start);
    const bool last = end == std::string_view::npos;
    if (last) end = text.size();
    ++number;
    std::string_view line = text.substr(start, end - start);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    const size_t first = line.find_first_not_of(" \t");
    const bool blank = first == std::string_view::npos;
    const bool comment = !blank && skip_comments && line[first] == '#';
    if (!blank && !comment) lines.push_back({number, line});
    if (last) break;
    start = end + 1;
  }
  return lines;
}

std::vector<std::string_view> SplitFields(std::string_view text) {
  std::vector<std::string_view> fields;
  size_t i = 0;
  while (i < text.size()) {
    while (i < text.size() && (text[i] == ' ' || text[i] == '\t' || text[i] == '\r')) ++i;
    if (i >= text.size()) break;
    size_t j = i;
    while (j < text.size() && text[j] != ' ' && text[j] != '\t' && text[j] != '\r') ++j;
    fields.push_back(text.substr(i, j - i));
    i = j;
  }
  return fields;
}

bool ParseDouble(std::string_view token, double* value) {
  if (token.empty() || token.size() > 64) return false;
  char buf[65];
  std::memcpy(buf, token.data(), token.size());
  buf[token.size()] = '\0';
  errno = 0;
  char* end = nullptr;
  const double v = std::strtod(buf, &end);
  if (end != buf + token.size() || errno == ERANGE || !std::isfinite(v)) {
    // ERANGE on underflow (denormals) is harmless; accept tiny values.
    if (!(end == buf + token.size() && errno == ERANGE && std::isfinite(v) && std::abs(v) < 1.0)) {
      return false;
    }
  }
  *value = v;
  return true;
}

bool ParseInt64(std::string_view token, int64_t* value) {
  if (token.empty() || token.size() > 24) return false;
  char buf[25];
  std::memcpy(buf, token.data(), token.size());
  buf[token.size()] = '\0';
  errno = 0;
  char* end = nullptr;
  const long long v = std::strtoll(buf, &end, 10);
  if (end != buf + token.size() || errno == ERANGE) return false;
  *value = static_cast<int64_t>(v);
  return true;
}

absl::Status LineError(const std::string& path, int line, const std::string& message) {
  return absl::InvalidArgumentError(path + ":" + std::to_string(line) + ": " + message);
}

absl::Status ParseNumberLine(const std::string& path,
                             const TextLine& line,
                             int count,
                             std::vector<double>* values) {
  const std::vector<std::string_view> fields = SplitFields(line.text);
  if (count >= 0 && static_cast<int>(fields.size()) != count) {
    return LineError(path,
                     line.number,
                     "expected " + std::to_string(count) + " numbers, found " +
                         std::to_string(fields.size()) + " fields");
  }
  values->resize(fields.size());
  for (size_t i = 0; i < fields.size(); ++i) {
    if (!ParseDouble(fields[i], &(*values)[i])) {
      return LineError(path,
                       line.number,
                       "field " + std::to_string(i + 1) + " '" + std::string(fields[i]) +
                           "' is not a finite number");
    }
  }
  return absl::OkStatus();
}

absl::Status WriteFileAtomic(const std::string& path, const std::string& contents) {
  // mkstemp gives a unique temporary next to the target (same filesystem, so
  // the rename is atomic) without any process-wide counter.
  std::string temp = path + ".tmp.XXXXXX";
  const int fd = ::mkstemp(temp.data());
  if (fd < 0) {
    return absl::FailedPreconditionError("cannot write " + path + ": " + std::strerror(errno));
  }
  size_t written = 0;
  while (written < contents.size()) {
    const ssize_t n = ::write(fd, contents.data() + written, contents.size() - written);
    if (n < 0) {
      if (errno == EINTR) continue;
      const std::string reason = std::strerror(errno);
      ::close(fd);
      std::remove(temp.c_str());
      return absl::DataLossError("cannot write " + path + ": " + reason);
    }
    written += static_cast<size_t>(n);
  }
  // mkstemp creates 0600; give the usual 0644 (subject to umask at open is not
  // applied by fchmod, so keep it conservative).
  ::fchmod(fd, 0644);
  if (::close(fd) != 0) {
    const std::string reason = std::strerror(errno);
    std::remove(temp.c_str());
    return absl::DataLossError("cannot write " + path + ": " + reason);
  }
  if (std::rename(temp.c_str(), path.c_str()) != 0) {
    const std::string reason = std::strerror(errno);
    std::remove(temp.c_str());
    return absl::FailedPreconditionError("cannot write " + path + ": rename failed: " + reason);
  }
  return absl::OkStatus();
}

bool FileExists(const std::string& path) {
  std::error_code ec;
  return std::filesystem::is_regular_file(path, ec);
}

bool DirExists(const std::string& path) {
  std::error_code ec;
  return std::filesystem::is_directory(path, ec);
}

std::string JoinPath(const std::string& a, const std::string& b) {
  if (a.empty()) return b;
  if (a.back() == '/') return a + b;
  return a + "/" + b;
}

std::string FormatDouble(double value) {
  char buf[40];
  for (int precision = 6; precision <= 17; ++precision) {
    std::snprintf(buf, sizeof(buf), "%.*g", precision, value);
    if (std::strtod(buf, nullptr) == value) break;
  }
  return buf;
}

}  // namespace twist::io
