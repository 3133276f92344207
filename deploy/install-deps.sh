#!/usr/bin/env bash
# Installs exactly the Debian 12 packages TwistSLAM needs to build, test and run.
# Idempotent: packages already present are skipped; apt-get update runs only
# when something is missing. This file is the only place that lists them.
set -euo pipefail

PACKAGES=(
  # toolchain
  build-essential cmake ninja-build ccache pkg-config git
  # math and optimisation
  libeigen3-dev libceres-dev libgoogle-glog-dev libgflags-dev
  # images, features, optical flow (libopencv-dev carries OpenCVConfig.cmake)
  libopencv-dev
  # service
  libgrpc++-dev libgrpc-dev protobuf-compiler-grpc libprotobuf-dev protobuf-compiler
  libabsl-dev libssl-dev
  # tests and benchmarks (python3-yaml + yamllint: deployment manifest checks)
  libgtest-dev libgmock-dev libbenchmark-dev python3 python3-yaml yamllint
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#PACKAGES[@]} packages present"
  exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
echo "install-deps: installing ${#missing[@]} packages: ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
echo "install-deps: done"
