#include "server/auth.h"

#include <fstream>
#include <sstream>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"

namespace twist::server {
namespace {

// FNV-1a 64: a stable, non-secret name for a token without a principal.
std::string StableTokenName(const std::string& token) {
  uint64_t h = 1469598103934665603ULL;
  for (unsigned char c : token) {
    h ^= c;
    h *= 1099511628211ULL;
  }
  char buf[17];
  snprintf(buf, sizeof(buf), "%016llx", static_cast<unsigned long long>(h));
  return absl::StrCat("token-", buf);
}

// Compares without an early exit on the first differing byte.
bool ConstantTimeEquals(const std::string& a, const std::string& b) {
  if (a.size() != b.size()) return false;
  unsigned char diff = 0;
  for (size_t i = 0; i < a.size(); ++i) diff |= static_cast<unsigned char>(a[i] ^ b[i]);
  return diff == 0;
}

}  // namespace

absl::StatusOr<TokenAuthenticator> TokenAuthenticator::FromText(const std::string& text) {
  TokenAuthenticator auth;
  int line_no = 0;
  for (absl::string_view raw : absl::StrSplit(text, '\n')) {
    ++line_no;
    const absl::string_view line = absl::StripAsciiWhitespace(raw);
    if (line.empty() || line[0] == '#') continue;
    std::vector<std::string> parts =
        absl::StrSplit(line, absl::ByAnyChar(" \t"), absl::SkipEmpty());
    if (parts.size() > 2) {
      return absl::InvalidArgumentError(
          absl::StrCat("token file line ", line_no, ": expected `<token> [<principal>]`"));
    }
    if (parts[0].size() < 8) {
      return absl::InvalidArgumentError(
          absl::StrCat("token file line ", line_no, ": token shorter than 8 characters"));
    }
    const std::string principal = parts.size() == 2 ? parts[1] : StableTokenName(parts[0]);
    if (!auth.principals_.emplace(parts[0], principal).second) {
      return absl::InvalidArgumentError(
          absl::StrCat("token file line ", line_no, ": duplicate token"));
    }
  }
  if (auth.principals_.empty()) return absl::InvalidArgumentError("token file has no tokens");
  return auth;
}

absl::StatusOr<TokenAuthenticator> TokenAuthenticator::FromFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) return absl::NotFoundError(absl::StrCat("cannot read token file ", path));
  std::stringstream ss;
  ss << in.rdbuf();
  absl::StatusOr<TokenAuthenticator> auth = FromText(ss.str());
  if (!auth.ok())
    return absl::InvalidArgumentError(absl::StrCat(path, ": ", auth.status().message()));
  return auth;
}

absl::StatusOr<std::string> TokenAuthenticator::AuthenticateHeader(
    const std::string& authorization) const {
  if (!enabled()) return std::string();
  if (authorization.empty()) {
    return absl::UnauthenticatedError("missing `authorization: Bearer <token>` metadata");
  }
  constexpr absl::string_view kPrefix = "Bearer ";
  if (!absl::StartsWithIgnoreCase(authorization, kPrefix)) {
    return absl::UnauthenticatedError("authorization metadata must be `Bearer <token>`");
  }
  const std::string token(
      absl::StripAsciiWhitespace(absl::string_view(authorization).substr(kPrefix.size())));
  for (const auto& [known, principal] : principals_) {
    if (ConstantTimeEquals(known, token)) return principal;
  }
  return absl::UnauthenticatedError("unknown bearer token");
}

absl::StatusOr<std::string> TokenAuthenticator::Authenticate(
    const grpc::ServerContext& context) const {
  if (!enabled()) return std::string();
  const auto& md = context.client_metadata();
  auto it = md.find("authorization");
  if (it == md.end()) return AuthenticateHeader("");
  return AuthenticateHeader(std::string(it->second.data(), it->second.size()));
}

}  // namespace twist::server
