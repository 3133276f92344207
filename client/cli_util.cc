#include "client/cli_util.h"

#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <sstream>
#include <system_error>

namespace twist::cli {

std::string Args::Get(const std::string& key, const std::string& fallback) const {
  auto it = values_.find(key);
  return it == values_.end() ? fallback : it->second;
}

std::optional<int64_t> Args::GetInt(const std::string& key, int64_t fallback) const {
  auto it = values_.find(key);
  if (it == values_.end()) return fallback;
  const std::string& s = it->second;
  if (s.empty()) return std::nullopt;
  errno = 0;
  char* end = nullptr;
  const long long v = std::strtoll(s.c_str(), &end, 10);
  if (errno != 0 || end != s.c_str() + s.size()) return std::nullopt;
  return static_cast<int64_t>(v);
}

std::optional<double> Args::GetDouble(const std::string& key, double fallback) const {
  auto it = values_.find(key);
  if (it == values_.end()) return fallback;
  const std::string& s = it->second;
  if (s.empty()) return std::nullopt;
  errno = 0;
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (errno != 0 || end != s.c_str() + s.size()) return std::nullopt;
  return v;
}

ArgParser& ArgParser::AddValue(const std::string& key,
                               const std::string& metavar,
                               const std::string& help,
                               bool required,
                               const std::string& default_text) {
  Option o;
  o.key = key;
  o.metavar = metavar;
  o.help = help;
  o.default_text = default_text;
  o.takes_value = true;
  o.required = required;
  options_.push_back(o);
  return *this;
}

ArgParser& ArgParser::AddFlag(const std::string& key, const std::string& help) {
  Option o;
  o.key = key;
  o.help = help;
  o.takes_value = false;
  options_.push_back(o);
  return *this;
}

const ArgParser::Option* ArgParser::Find(const std::string& key) const {
  for (const Option& o : options_) {
    if (o.key == key) return &o;
  }
  return nullptr;
}

std::string ArgParser::Usage() const {
  std::ostringstream out;
  out << "usage: twistslam " << command_;
  for (const Option& o : options_) {
    std::string item = "--" + o.key + (o.takes_value ? " " + o.metavar : "");
    out << " " << (o.required ? item : "[" + item + "]");
  }
  out << "\n";
  for (const Option& o : options_) {
    std::string item = "--" + o.key + (o.takes_value ? " " + o.metavar : "");
    out << "  " << item;
    if (item.size() < 24) out << std::string(24 - item.size(), ' ');
    out << " " << o.help;
    if (!o.default_text.empty()) out << " (default " << o.default_text << ")";
    out << "\n";
  }
  return out.str();
}

std::optional<Args> ArgParser::Parse(int argc, char** argv) {
  Args args;
  for (int i = 1; i < argc; ++i) {
    std::string token = argv[i];
    if (token == "--help" || token == "-h") {
      std::cout << Usage();
      exit_code_ = 0;
      return std::nullopt;
    }
    if (token.size() < 3 || token.compare(0, 2, "--") != 0) {
      exit_code_ = Fail(command_, "unexpected argument '" + token + "' (try --help)", 2);
      return std::nullopt;
    }
    std::string key = token.substr(2);
    std::optional<std::string> inline_value;
    const size_t eq = key.find('=');
    if (eq != std::string::npos) {
      inline_value = key.substr(eq + 1);
      key = key.substr(0, eq);
    }
    const Option* option = Find(key);
    if (option == nullptr) {
      exit_code_ = Fail(command_, "unknown option --" + key + " (try --help)", 2);
      return std::nullopt;
    }
    if (!option->takes_value) {
      if (inline_value) {
        exit_code_ = Fail(command_, "option --" + key + " takes no value", 2);
        return std::nullopt;
      }
      args.flags_.insert(key);
      continue;
    }
    if (inline_value) {
      args.values_[key] = *inline_value;
    } else {
      if (i + 1 >= argc) {
        exit_code_ = Fail(command_, "option --" + key + " needs a value " + option->metavar, 2);
        return std::nullopt;
      }
      args.values_[key] = argv[++i];
    }
  }
  for (const Option& o : options_) {
    if (o.required && !args.Has(o.key)) {
      exit_code_ = Fail(command_, "missing required option --" + o.key + " " + o.metavar, 2);
      return std::nullopt;
    }
  }
  exit_code_ = 0;
  return args;
}

std::string OneLine(const std::string& message) {
  std::string out;
  out.reserve(message.size());
  for (size_t i = 0; i < message.size(); ++i) {
    const char c = message[i];
    if (c == '\r') continue;
    if (c == '\n') {
      if (i + 1 < message.size()) out += "; ";
      continue;
    }
    out += c;
  }
  return out;
}

int Fail(const std::string& command, const std::string& message, int exit_code) {
  std::cerr << "twistslam " << command << ": " << OneLine(message) << std::endl;
  return exit_code;
}

namespace {

std::string TempPathFor(const std::string& path) {
  // Same directory (rename stays on one filesystem); pid + address make it
  // unique between processes and between concurrent writers in one process.
  static_assert(sizeof(void*) <= sizeof(unsigned long long), "pointer size");
  std::ostringstream s;
  s << path << ".tmp." << ::getpid() << "." << std::hex
    << reinterpret_cast<unsigned long long>(&path);
  return s.str();
}

}  // namespace

bool WriteFileAtomic(const std::string& path, const std::string& contents, std::string* error) {
  AtomicFile file(path);
  if (!file.ok()) {
    if (error) *error = "cannot write " + path + ": " + std::strerror(errno);
    return false;
  }
  file.stream().write(contents.data(), static_cast<std::streamsize>(contents.size()));
  return file.Commit(error);
}

AtomicFile::AtomicFile(std::string path) : path_(std::move(path)) {
  temp_path_ = TempPathFor(path_);
  stream_.open(temp_path_, std::ios::out | std::ios::binary | std::ios::trunc);
}

AtomicFile::~AtomicFile() {
  if (!committed_) {
    if (stream_.is_open()) stream_.close();
    std::remove(temp_path_.c_str());
  }
}

bool AtomicFile::Commit(std::string* error) {
  if (committed_) return true;
  if (!stream_.is_open()) {
    if (error) *error = "cannot write " + path_ + ": could not create " + temp_path_;
    return false;
  }
  stream_.flush();
  const bool write_ok = stream_.good();
  stream_.close();
  if (!write_ok || stream_.fail()) {
    if (error) *error = "cannot write " + path_ + ": write failed (disk full?)";
    std::remove(temp_path_.c_str());
    return false;
  }
  if (std::rename(temp_path_.c_str(), path_.c_str()) != 0) {
    if (error) *error = "cannot write " + path_ + ": rename failed: " + std::strerror(errno);
    std::remove(temp_path_.c_str());
    return false;
  }
  committed_ = true;
  return true;
}

bool MakeDirs(const std::string& dir, std::string* error) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec || !std::filesystem::is_directory(dir)) {
    if (error)
      *error = "cannot create directory " + dir + ": " + (ec ? ec.message() : "not a directory");
    return false;
  }
  return true;
}

}  // namespace twist::cli
