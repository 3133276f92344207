// Optional bearer-token authentication. Tokens come from a file, one per
// line: `<token> [<principal>]` (blank lines and lines starting with # are
// ignored). A call carries `authorization: Bearer <token>`. The principal
// (the given name, else a stable hash of the token) owns the sessions it
// creates; other principals cannot see them.
#pragma once

#include <grpcpp/server_context.h>

#include <map>
#include <string>

#include "absl/status/statusor.h"

namespace twist::server {

class TokenAuthenticator {
 public:
  // Authentication disabled: every call is the anonymous principal "".
  TokenAuthenticator() = default;

  static absl::StatusOr<TokenAuthenticator> FromFile(const std::string& path);
  // Parses the file format above (for tests and FromFile).
  static absl::StatusOr<TokenAuthenticator> FromText(const std::string& text);

  bool enabled() const { return !principals_.empty(); }

  // The caller's principal; UNAUTHENTICATED when auth is on and the token is
  // missing, malformed or unknown.
  absl::StatusOr<std::string> Authenticate(const grpc::ServerContext& context) const;
  absl::StatusOr<std::string> AuthenticateHeader(const std::string& authorization) const;

 private:
  std::map<std::string, std::string> principals_;  // token -> principal
};

}  // namespace twist::server
