#include "server/server_flags.h"

#include <filesystem>
#include <functional>
#include <map>
#include <opencv2/core/persistence.hpp>

#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "slam/common/config_text.h"

namespace twist::server {
namespace {

absl::Status ParseInt(
    const std::string& flag, const std::string& v, int64_t lo, int64_t hi, int64_t* out) {
  int64_t x = 0;
  if (!absl::SimpleAtoi(v, &x) || x < lo || x > hi) {
    return absl::InvalidArgumentError(
        absl::StrCat(flag, ": '", v, "' is not an integer in [", lo, ", ", hi, "]"));
  }
  *out = x;
  return absl::OkStatus();
}

absl::Status ParseDouble(
    const std::string& flag, const std::string& v, double lo, double hi, double* out) {
  double x = 0;
  if (!absl::SimpleAtod(v, &x) || !(x >= lo && x <= hi)) {
    return absl::InvalidArgumentError(
        absl::StrCat(flag, ": '", v, "' is not a number in [", lo, ", ", hi, "]"));
  }
  *out = x;
  return absl::OkStatus();
}

// One setting, settable from the command line (--name) and the config file
// (name with '-' -> '_').
struct Setting {
  const char* name;
  const char* help;
  std::function<absl::Status(const std::string& flag, const std::string& value, ServerOptions*)>
      set;
};

std::vector<Setting> Settings() {
  auto str = [](std::string ServerOptions::*field) {
    return [field](const std::string&, const std::string& v, ServerOptions* o) {
      o->*field = v;
      return absl::OkStatus();
    };
  };
  auto dbl = [](double lo, double hi, std::function<double*(ServerOptions*)> field) {
    return [=](const std::string& flag, const std::string& v, ServerOptions* o) {
      return ParseDouble(flag, v, lo, hi, field(o));
    };
  };
  auto integer = [](int64_t lo, int64_t hi, std::function<void(ServerOptions*, int64_t)> set) {
    return [=](const std::string& flag, const std::string& v, ServerOptions* o) {
      int64_t x = 0;
      if (absl::Status s = ParseInt(flag, v, lo, hi, &x); !s.ok()) return s;
      set(o, x);
      return absl::OkStatus();
    };
  };
  return {
      {"listen",
       "HOST:PORT to serve on (port 0: any free port) [127.0.0.1:0]",
       str(&ServerOptions::listen)},
      {"state-dir",
       "directory for persisted sessions (enables persistence)",
       [](const std::string&, const std::string& v, ServerOptions* o) {
         o->sessions.state_dir = v;
         return absl::OkStatus();
       }},
      {"auth-token-file",
       "file of bearer tokens (`<token> [<principal>]` per line); enables auth",
       str(&ServerOptions::auth_token_file)},
      {"tls-cert",
       "PEM certificate chain (with --tls-key enables TLS)",
       str(&ServerOptions::tls_cert_file)},
      {"tls-key", "PEM private key", str(&ServerOptions::tls_key_file)},
      {"metrics-listen",
       "HOST:PORT of the Prometheus /metrics endpoint (off by default)",
       str(&ServerOptions::metrics_listen)},
      {"max-sessions",
       "sessions loaded at once [16]",
       integer(
           1,
           100000,
           [](ServerOptions* o, int64_t x) { o->sessions.max_sessions = static_cast<int>(x); })},
      {"max-message-mb",
       "largest gRPC message in MiB, >= 4 [64]",
       integer(4, 1024, [](ServerOptions* o, int64_t x) { o->max_message_bytes = x << 20; })},
      {"queue-capacity",
       "default per-session input queue (frames) [4]",
       integer(1,
               4096,
               [](ServerOptions* o, int64_t x) {
                 o->sessions.limits.default_queue_capacity = static_cast<int>(x);
               })},
      {"max-queue-capacity",
       "largest per-session input queue a client may ask for [64]",
       integer(1,
               4096,
               [](ServerOptions* o, int64_t x) {
                 o->sessions.limits.max_queue_capacity = static_cast<int>(x);
               })},
      {"idle-timeout-s",
       "default idle-session expiry in seconds [600]",
       dbl(0.001,
           1e9,
           [](ServerOptions* o) { return &o->sessions.limits.default_idle_timeout_s; })},
      {"max-idle-timeout-s",
       "largest idle expiry a client may ask for [604800]",
       dbl(0.001, 1e9, [](ServerOptions* o) { return &o->sessions.limits.max_idle_timeout_s; })},
      {"persist-interval-s",
       "periodic save of changed sessions, 0 = off [60]",
       dbl(0, 1e9, [](ServerOptions* o) { return &o->sessions.persist_interval_s; })},
      {"drain-timeout-s",
       "shutdown: time for streams to answer queued frames [5]",
       dbl(0, 3600, [](ServerOptions* o) { return &o->drain_timeout_s; })},
      {"shutdown-deadline-s",
       "shutdown: hard deadline for open calls [10]",
       dbl(0, 3600, [](ServerOptions* o) { return &o->shutdown_deadline_s; })},
      {"max-image-size",
       "largest image side in pixels [8192]",
       integer(16,
               65536,
               [](ServerOptions* o, int64_t x) {
                 o->sessions.limits.max_image_width = static_cast<int>(x);
                 o->sessions.limits.max_image_height = static_cast<int>(x);
               })},
      {"threads",
       "gRPC sync-server polling threads, 0 = gRPC default [0]",
       integer(0,
               1024,
               [](ServerOptions* o, int64_t x) { o->sync_server_threads = static_cast<int>(x); })},
  };
}

// Engine defaults (SlamOptions) from the config file's `slam` map.
absl::Status ReadSlamOptions(const cv::FileNode& node, SlamOptions* o) {
  if (node.empty()) return absl::OkStatus();
  if (!node.isMap()) return absl::InvalidArgumentError("config: `slam` must be a map");
  for (cv::FileNodeIterator it = node.begin(); it != node.end(); ++it) {
    const cv::FileNode n = *it;
    const std::string key = n.name();
    if (key == "mapping_mode") {
      const std::string v = n.string();
      if (v == "synchronous") {
        o->mapping_mode = MappingMode::kSynchronous;
      } else if (v == "background") {
        o->mapping_mode = MappingMode::kBackground;
      } else {
        return absl::InvalidArgumentError(
            "config: slam.mapping_mode must be synchronous or background");
      }
      continue;
    }
    if (!n.isReal() && !n.isInt()) {
      return absl::InvalidArgumentError(absl::StrCat("config: slam.", key, " must be a number"));
    }
    const double v = n.real();
    if (!SetNumericSlamOption(key, v, o))
      return absl::InvalidArgumentError(absl::StrCat("config: unknown key slam.", key));
  }
  return absl::OkStatus();
}

absl::Status ApplyConfigFile(const std::string& path, ServerOptions* options) {
  if (!std::filesystem::exists(path))
    return absl::NotFoundError(absl::StrCat("--config ", path, ": no such file"));
  const std::optional<std::string> text = ReadConfigText(path);
  if (!text.has_value()) {
    return absl::InvalidArgumentError(absl::StrCat("--config ", path, ": cannot read"));
  }
  cv::FileStorage fs;
  try {
    if (!fs.open(*text, cv::FileStorage::READ | cv::FileStorage::MEMORY)) {
      return absl::InvalidArgumentError(
          absl::StrCat("--config ", path, ": cannot parse (YAML or JSON expected)"));
    }
  } catch (const cv::Exception& e) {
    return absl::InvalidArgumentError(absl::StrCat("--config ", path, ": ", e.what()));
  }
  std::map<std::string, Setting> by_key;
  for (const Setting& s : Settings()) {
    std::string key = s.name;
    std::replace(key.begin(), key.end(), '-', '_');
    by_key.emplace(key, s);
  }
  const cv::FileNode root = fs.root();
  for (cv::FileNodeIterator it = root.begin(); it != root.end(); ++it) {
    const cv::FileNode n = *it;
    const std::string key = n.name();
    if (key == "slam") {
      if (absl::Status s = ReadSlamOptions(n, &options->sessions.limits.default_options); !s.ok())
        return s;
      continue;
    }
    auto found = by_key.find(key);
    if (found == by_key.end())
      return absl::InvalidArgumentError(absl::StrCat("--config ", path, ": unknown key ", key));
    std::string value;
    if (n.isString()) {
      value = n.string();
    } else if (n.isInt()) {
      value = absl::StrCat(static_cast<int64_t>(n.real()));
    } else if (n.isReal()) {
      value = absl::StrCat(n.real());
    } else {
      return absl::InvalidArgumentError(
          absl::StrCat("--config ", path, ": ", key, " must be a scalar"));
    }
    if (absl::Status s = found->second.set(key, value, options); !s.ok()) {
      return absl::InvalidArgumentError(absl::StrCat("--config ", path, ": ", s.message()));
    }
  }
  return absl::OkStatus();
}

}  // namespace

std::string ServerUsage() {
  std::string out =
      "usage: twistslam-server --listen HOST:PORT [--config FILE] [--state-dir DIR]\n"
      "                        [--auth-token-file FILE] [--tls-cert FILE --tls-key FILE] "
      "[options]\n\n"
      "options:\n"
      "  --config FILE            YAML/JSON file with any option below (key with '_') and a "
      "`slam:` map\n";
  for (const Setting& s : Settings()) {
    absl::StrAppend(&out,
                    "  --",
                    s.name,
                    std::string(std::max<size_t>(1, 23 - strlen(s.name)), ' '),
                    s.help,
                    "\n");
  }
  absl::StrAppend(&out,
                  "  --v N                    verbose logging level (glog VLOG)\n",
                  "\nWith port 0 the first line on stdout is `listening on HOST:PORT`.\n"
                  "SIGTERM/SIGINT shut down gracefully (drain, persist, stop).\n");
  return out;
}

absl::StatusOr<ParsedServerFlags> ParseServerFlags(int argc, char** argv) {
  ParsedServerFlags parsed;
  std::map<std::string, std::string> values;
  std::vector<std::string> order;
  std::string config;
  for (int i = 1; i < argc; ++i) {
    std::string arg = argv[i];
    if (arg == "--help" || arg == "-h") {
      parsed.help = true;
      return parsed;
    }
    if (!absl::StartsWith(arg, "--"))
      return absl::InvalidArgumentError(absl::StrCat("unexpected argument '", arg, "'"));
    std::string key = arg.substr(2), value;
    const size_t eq = key.find('=');
    if (eq != std::string::npos) {
      value = key.substr(eq + 1);
      key = key.substr(0, eq);
    } else {
      if (i + 1 >= argc)
        return absl::InvalidArgumentError(absl::StrCat("--", key, " needs a value"));
      value = argv[++i];
    }
    if (key == "config") {
      config = value;
    } else if (key == "v") {
      int64_t v = 0;
      if (absl::Status s = ParseInt("--v", value, 0, 9, &v); !s.ok()) return s;
      parsed.verbosity = static_cast<int>(v);
    } else {
      values[key] = value;
      order.push_back(key);
    }
  }
  if (!config.empty()) {
    if (absl::Status s = ApplyConfigFile(config, &parsed.options); !s.ok()) return s;
  }
  const std::vector<Setting> settings = Settings();
  for (const std::string& key : order) {
    auto it = std::find_if(
        settings.begin(), settings.end(), [&](const Setting& s) { return key == s.name; });
    if (it == settings.end())
      return absl::InvalidArgumentError(absl::StrCat("unknown flag --", key));
    if (absl::Status s = it->set("--" + key, values[key], &parsed.options); !s.ok()) return s;
  }
  const auto& l = parsed.options.sessions.limits;
  if (l.default_queue_capacity > l.max_queue_capacity) {
    return absl::InvalidArgumentError("--queue-capacity exceeds --max-queue-capacity");
  }
  if (l.default_idle_timeout_s > l.max_idle_timeout_s) {
    return absl::InvalidArgumentError("--idle-timeout-s exceeds --max-idle-timeout-s");
  }
  return parsed;
}

}  // namespace twist::server
