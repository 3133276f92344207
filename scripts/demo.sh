#!/usr/bin/env bash
# The main job on a fresh Debian 12 machine: installs dependencies, builds,
# starts a local server on loopback (free port), generates a synthetic street
# sequence with moving cars, streams it through the server, prints the
# metrics and writes outputs and pictures to out/demo/.
# Env: SCENARIO (default driving), FRAMES (default 60), OUT (default out/demo).
set -euo pipefail
cd "$(dirname "$0")/.."
bash deploy/install-deps.sh
BUILD_DIR=${BUILD_DIR:-build}
SCENARIO=${SCENARIO:-driving}
FRAMES=${FRAMES:-60}
OUT=${OUT:-out/demo}
export CCACHE_DIR=${CCACHE_DIR:-$HOME/.cache/ccache}
# Paths relative to the checkout, so clones in other folders hit the cache.
export CCACHE_BASEDIR=${CCACHE_BASEDIR:-$PWD}
cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release -DTWIST_BUILD_TESTS=ON -DTWIST_WERROR=ON >/dev/null
cmake --build "$BUILD_DIR" -j "$(nproc)" --target twistslam twistslam-server

bin="$BUILD_DIR"
rm -rf "$OUT" && mkdir -p "$OUT"
echo "== generating scenario '$SCENARIO' ($FRAMES frames)"
"$bin/client/twistslam" generate --scenario "$SCENARIO" --frames "$FRAMES" --out "$OUT/data"

echo "== starting server on 127.0.0.1 (free port)"
"$bin/server/twistslam-server" --listen 127.0.0.1:0 --state-dir "$OUT/state" >"$OUT/server.out" 2>"$OUT/server.log" &
server_pid=$!
trap 'kill -TERM $server_pid 2>/dev/null || true; wait $server_pid 2>/dev/null || true' EXIT
addr=""
for _ in $(seq 1 100); do
  addr=$(sed -n 's/^listening on //p' "$OUT/server.out" | head -n1)
  [ -n "$addr" ] && break
  kill -0 $server_pid 2>/dev/null || { cat "$OUT/server.log" >&2; echo "demo: server exited" >&2; exit 1; }
  sleep 0.1
done
[ -n "$addr" ] || { echo "demo: server did not report its address" >&2; exit 1; }
echo "   server at $addr"

echo "== streaming through the server"
"$bin/client/twistslam" run --server "$addr" --dataset "$OUT/data" --format kitti-tracking --seq 0000 --out "$OUT/run"

echo "== metrics"
"$bin/client/twistslam" eval --dataset "$OUT/data" --format kitti-tracking --seq 0000 --est "$OUT/run" --json "$OUT/run/metrics.json"
echo "== metrics of the objects' trajectories as the dynamic BA left them (objects_refined.txt)"
"$bin/client/twistslam" eval --dataset "$OUT/data" --format kitti-tracking --seq 0000 --est "$OUT/run" --refined --json "$OUT/run/metrics_refined.json" | sed -n '/^objects from/,$p'

echo "== pictures"
"$bin/client/twistslam" plot --est "$OUT/run" --dataset "$OUT/data" --format kitti-tracking --seq 0000
echo "outputs in $OUT/run:"
ls "$OUT/run"
