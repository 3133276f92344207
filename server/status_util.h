// The one place where absl::Status meets grpc::Status (DESIGN.md §3): the
// engine and the server logic speak absl::Status, the wire speaks grpc.
#pragma once

#include <grpcpp/support/status.h>

#include "absl/status/status.h"

namespace twist::server {

// Maps every absl code to the grpc code of the same number and keeps the
// message; OK stays OK.
grpc::Status ToGrpcStatus(const absl::Status& status);
// The reverse (used by the client library and tests).
absl::Status FromGrpcStatus(const grpc::Status& status);

}  // namespace twist::server
