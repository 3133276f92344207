#!/usr/bin/env bash
# Container test: builds the TwistSLAM image from deploy/Dockerfile without a
# Docker engine (podman/buildah, ../shared/docs/CONTAINERS.md), starts the
# server from the image on the host's loopback, streams a generated synthetic
# sequence to it with the host-built client, checks the results and the
# graceful shutdown, and cleans up.
#
#   sudo bash tests/container/run_container_test.sh [options]
#     --client PATH   host-built `twistslam` (default: $BUILD_DIR/client/twistslam,
#                     BUILD_DIR=build); if absent the image's own client runs
#                     in a second working container instead
#     --worktree      build from the working tree (default: the committed HEAD,
#                     via `git archive`, so uncommitted files cannot leak in)
#     --frames N      frames of the synthetic sequence (default 30)
#     --scenario S    generator scenario (default: driving)
#     --prebuilt DIR  package the executables in DIR (twistslam-server,
#                     twistslam, twistslam-health-probe, built on Debian 12)
#                     instead of compiling inside the image (build arg
#                     PREBUILT): tests everything but the compile stage, for
#                     machines too busy to compile the project twice
#     --rmi           remove the built image localhost/twistslam:test at the
#                     end (default: keep it, so a rebuild reuses its layers)
#
# Needs root and the Debian packages podman, buildah, debootstrap (the base
# image is debootstrapped once and cached: /var/tmp/twistslam-container and
# the local image localhost/debian:bookworm). The image build compiles the
# project inside the image: on 2 cores expect tens of minutes (measured figure
# in docs/deploy.md).
#
# Exit 0 when every check passed; the last line is "N passed, M failed".
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BUILD_DIR=${BUILD_DIR:-$ROOT/build}
CLIENT="$BUILD_DIR/client/twistslam"
USE_WORKTREE=0
FRAMES=30
SCENARIO=driving
REMOVE_IMAGE=0
PREBUILT=""
IMAGE=localhost/twistslam:test
BASE_IMAGE=localhost/debian:bookworm
CACHE=/var/tmp/twistslam-container

while [ $# -gt 0 ]; do
  case "$1" in
    --client) CLIENT=$2; shift 2 ;;
    --worktree) USE_WORKTREE=1; shift ;;
    --frames) FRAMES=$2; shift 2 ;;
    --scenario) SCENARIO=$2; shift 2 ;;
    --rmi) REMOVE_IMAGE=1; shift ;;
    --prebuilt) PREBUILT=$2; shift 2 ;;
    -h|--help) sed -n '2,30p' "$0"; exit 0 ;;
    *) echo "run_container_test: unknown option $1" >&2; exit 2 ;;
  esac
done

passed=0
failed=0
ok() { echo "PASS $*"; passed=$((passed + 1)); }
bad() { echo "FAIL $*"; failed=$((failed + 1)); }
check() {  # check "description" command...
  local what=$1; shift
  if "$@"; then ok "$what"; else bad "$what"; fi
}
now() { date +%s; }
T0=$(now)
log() { printf '[%4ds] %s\n' "$(( $(now) - T0 ))" "$*"; }

[ "$(id -u)" -eq 0 ] || { echo "run_container_test: run as root (podman/buildah chroot isolation)" >&2; exit 2; }
# The container tools are this test's own dependencies (not the build's), so
# they are installed here rather than in deploy/install-deps.sh.
for tool in podman buildah debootstrap git python3; do
  if ! command -v "$tool" >/dev/null; then
    echo "run_container_test: installing podman buildah debootstrap git python3" >&2
    DEBIAN_FRONTEND=noninteractive apt-get update -qq &&
      DEBIAN_FRONTEND=noninteractive apt-get install -y -qq podman buildah debootstrap git python3 >/dev/null ||
      { echo "run_container_test: could not install the container tools" >&2; exit 2; }
    break
  fi
done

WORK=$(mktemp -d /var/tmp/twistslam-ctest.XXXXXX)
CONTAINERS=()
SERVER_PID=""
cleanup() {
  set +e
  if [ -n "$SERVER_PID" ] && kill -0 "$SERVER_PID" 2>/dev/null; then
    kill "$SERVER_PID" 2>/dev/null
    wait "$SERVER_PID" 2>/dev/null
  fi
  for c in "${CONTAINERS[@]}"; do buildah rm "$c" >/dev/null 2>&1; done
  if [ "$REMOVE_IMAGE" -eq 1 ]; then podman rmi -f "$IMAGE" >/dev/null 2>&1; fi
  rm -rf "$WORK"
}
trap cleanup EXIT

# --- 1. Local Debian 12 base image (cached). ---------------------------------
if ! podman image exists "$BASE_IMAGE"; then
  log "debootstrapping $BASE_IMAGE (cached in $CACHE)"
  mkdir -p "$CACHE"
  if [ ! -x "$CACHE/rootfs/bin/sh" ]; then
    rm -rf "$CACHE/rootfs"
    debootstrap --variant=minbase bookworm "$CACHE/rootfs" >"$CACHE/debootstrap.log" 2>&1
  fi
  tar -C "$CACHE/rootfs" -c . | podman import - "$BASE_IMAGE" >/dev/null
fi
ok "base image $BASE_IMAGE"

# --- 2. Build the image. -----------------------------------------------------
if [ "$USE_WORKTREE" -eq 1 ]; then
  CONTEXT=$ROOT
  log "building $IMAGE from the working tree"
else
  CONTEXT=$WORK/context
  mkdir -p "$CONTEXT"
  git -C "$ROOT" archive --format=tar HEAD | tar -C "$CONTEXT" -x
  # Buildah's layer cache keys COPY on file metadata too: a fixed mtime keeps
  # the dependency layer (COPY deploy/install-deps.sh + RUN) cached across
  # runs as long as the script's content is unchanged.
  find "$CONTEXT" -exec touch -h -d @1700000000 {} +
  log "building $IMAGE from HEAD $(git -C "$ROOT" rev-parse --short HEAD)"
fi
BUILD_ARGS=(--build-arg BASE="$BASE_IMAGE")
if [ -n "$PREBUILT" ]; then
  if [ "$USE_WORKTREE" -eq 1 ]; then
    echo "run_container_test: --prebuilt needs the HEAD context (no --worktree)" >&2; exit 2
  fi
  mkdir -p "$CONTEXT/prebuilt"
  for exe in twistslam-server twistslam twistslam-health-probe; do
    cp "$PREBUILT/$exe" "$CONTEXT/prebuilt/" || { echo "run_container_test: $PREBUILT/$exe missing" >&2; exit 2; }
  done
  BUILD_ARGS+=(--build-arg PREBUILT=prebuilt)
  log "packaging prebuilt executables from $PREBUILT (no compile in the image)"
fi
T_BUILD=$(now)
if podman build --format docker --isolation chroot \
     "${BUILD_ARGS[@]}" -t "$IMAGE" \
     -f "$CONTEXT/deploy/Dockerfile" "$CONTEXT" >"$WORK/build.log" 2>&1; then
  BUILD_S=$(( $(now) - T_BUILD ))
  ok "image build (${BUILD_S} s)"
else
  BUILD_S=$(( $(now) - T_BUILD ))
  tail -n 40 "$WORK/build.log"
  bad "image build (${BUILD_S} s)"
  echo "$passed passed, $failed failed"
  exit 1
fi
cp "$WORK/build.log" "$CACHE/last-build.log" 2>/dev/null || true
grep -A30 '^runtime packages:' "$WORK/build.log" | sed -n '1,30p' | grep -v '^-->' || true

# --- 3. Image metadata. ------------------------------------------------------
inspect() { podman image inspect --format "$1" "$IMAGE"; }
check "runs as non-root user 10001" test "$(inspect '{{.Config.User}}')" = "10001:10001"
check "state volume /var/lib/twistslam" grep -q /var/lib/twistslam <<<"$(inspect '{{json .Config.Volumes}}')"
check "exposes 50051" grep -q 50051 <<<"$(inspect '{{json .Config.ExposedPorts}}')"
check "healthcheck uses the probe" grep -q twistslam-health-probe <<<"$(inspect '{{json .Config.Healthcheck}}')"
check "entrypoint is the server" grep -q twistslam-server <<<"$(inspect '{{json .Config.Entrypoint}}')"
SIZE_MB=$(( $(inspect '{{.Size}}') / 1000000 ))
log "image size ${SIZE_MB} MB"
check "no compiler in the runtime image" bash -c \
  "c=\$(buildah from $IMAGE) && trap 'buildah rm \$c >/dev/null' EXIT && \
   ! buildah run --isolation chroot \$c -- sh -c 'command -v c++ || command -v cmake' >/dev/null 2>&1"

# --- 4. Start the server from the image on a free loopback port. ------------
C=$(buildah from "$IMAGE")
CONTAINERS+=("$C")
check "container user is 10001" test "$(buildah run --isolation chroot "$C" -- id -u)" = 10001
T_START=$(now)
buildah run --isolation chroot "$C" -- /usr/local/bin/twistslam-server \
  --listen 127.0.0.1:0 --state-dir /var/lib/twistslam --config /etc/twistslam/server.yaml \
  >"$WORK/server.out" 2>"$WORK/server.err" </dev/null &
SERVER_PID=$!
ADDR=""
for _ in $(seq 1 600); do
  line=$(head -n 1 "$WORK/server.out" 2>/dev/null || true)
  if [[ "$line" == "listening on "* ]]; then ADDR=${line#listening on }; break; fi
  kill -0 "$SERVER_PID" 2>/dev/null || break
  sleep 0.1
done
if [ -z "$ADDR" ]; then
  bad "server started (first stdout line 'listening on ADDR')"
  tail -n 20 "$WORK/server.err"
  echo "$passed passed, $failed failed"
  exit 1
fi
ok "server listening on $ADDR after $(( $(now) - T_START )) s"

# The health probe from the image, as the HEALTHCHECK runs it.
C2=$(buildah from "$IMAGE")
CONTAINERS+=("$C2")
check "health probe (in image) reports SERVING" \
  buildah run --isolation chroot "$C2" -- /usr/local/bin/twistslam-health-probe \
    --addr "$ADDR" --wait-ms 30000

# --- 5. End to end with the client. -----------------------------------------
if [ -x "$CLIENT" ]; then
  log "client: host-built $CLIENT"
  client() { "$CLIENT" "$@"; }
  DATA=$WORK/data
  OUT=$WORK/out
else
  log "client: $CLIENT not found, using the image's twistslam in a working container"
  buildah run --isolation chroot "$C2" -- mkdir -p /var/lib/twistslam/e2e
  client() { buildah run --isolation chroot --workingdir /var/lib/twistslam/e2e "$C2" -- twistslam "$@"; }
  DATA=/var/lib/twistslam/e2e/data
  OUT=/var/lib/twistslam/e2e/out
fi
T_E2E=$(now)
check "twistslam generate --scenario $SCENARIO --frames $FRAMES" \
  client generate --scenario "$SCENARIO" --out "$DATA" --frames "$FRAMES" --seed 7
if [ -x "$CLIENT" ]; then
  SEQ=$(ls "$DATA/image_02" 2>/dev/null | head -n 1)
else
  SEQ=$(buildah run --isolation chroot "$C2" -- ls "$DATA/image_02" | head -n 1)
fi
SEQ=${SEQ:-0000}
check "twistslam run --server $ADDR" \
  client run --dataset "$DATA" --format kitti-tracking --seq "$SEQ" --out "$OUT" --server "$ADDR" \
    --keep-session
check "twistslam eval" \
  client eval --dataset "$DATA" --format kitti-tracking --seq "$SEQ" --est "$OUT" --json "$OUT/metrics.json"
E2E_S=$(( $(now) - T_E2E ))
if [ ! -x "$CLIENT" ]; then
  # Bring the outputs to the host for the checks.
  MNT=$(buildah mount "$C2")
  mkdir -p "$WORK/out" "$WORK/data"
  cp -r "$MNT$OUT/." "$WORK/out/" && cp -r "$MNT$DATA/." "$WORK/data/"
  buildah umount "$C2" >/dev/null
  DATA=$WORK/data
  OUT=$WORK/out
fi

# --- 6. Check the results. ----------------------------------------------------
FRAMES_ON_DISK=$(ls "$DATA/image_02/$SEQ" 2>/dev/null | wc -l)
check "camera.txt has one pose per frame ($FRAMES_ON_DISK)" python3 - "$OUT/camera.txt" "$FRAMES_ON_DISK" <<'EOF'
import math, sys
path, frames = sys.argv[1], int(sys.argv[2])
rows = [l.split() for l in open(path) if l.strip()]
assert frames > 0, "no frames generated"
assert len(rows) == frames, f"{len(rows)} poses for {frames} frames"
for r in rows:
    assert len(r) == 12, f"KITTI pose rows have 12 numbers, got {len(r)}"
    v = [float(x) for x in r]
    assert all(math.isfinite(x) for x in v)
    R = [[v[0], v[1], v[2]], [v[4], v[5], v[6]], [v[8], v[9], v[10]]]
    for i in range(3):  # rows of a rotation are unit vectors
        assert abs(sum(x * x for x in R[i]) - 1) < 1e-3, "not a rotation"
EOF
check "metrics are finite and sane" python3 - "$OUT/metrics.json" <<'EOF'
import json, math, sys
metrics = json.load(open(sys.argv[1]))
numbers = {}
def walk(prefix, node):
    if isinstance(node, dict):
        for k, v in node.items():
            walk(f"{prefix}.{k}" if prefix else k, v)
    elif isinstance(node, (int, float)) and not isinstance(node, bool):
        numbers[prefix] = float(node)
walk("", metrics)
print("  " + ", ".join(f"{k}={v:.4g}" for k, v in sorted(numbers.items())))
assert numbers, "no numbers in metrics.json"
assert all(math.isfinite(v) for v in numbers.values()), "non-finite metric"
ate = [v for k, v in numbers.items() if "ate" in k.lower() and "camera" in k.lower()] or \
      [v for k, v in numbers.items() if "ate" in k.lower()]
assert ate, "no ATE in metrics.json"
# The synthetic scene is tens of metres long: a working tracker stays well
# under a metre of camera ATE; a broken one drifts far beyond.
assert min(ate) < 1.0, f"camera ATE {min(ate)} m"
EOF

# --- 7. Graceful shutdown: SIGTERM to the server process itself. -------------
# (buildah does not forward SIGTERM to the containerised process, so find the
# server among the descendants of the buildah process this script started.)
descendant() {  # descendant PID NAME -> pid of the first descendant named NAME
  local pid=$1 name=$2 child
  for child in $(cat /proc/"$pid"/task/*/children 2>/dev/null); do
    if [ "$(cat /proc/"$child"/comm 2>/dev/null)" = "$name" ]; then echo "$child"; return 0; fi
    descendant "$child" "$name" && return 0
  done
  return 1
}
SERVER_INNER=$(descendant "$SERVER_PID" twistslam-serve || true)  # comm is 15 chars
if [ -n "$SERVER_INNER" ]; then
  T_STOP=$(now)
  kill -TERM "$SERVER_INNER"
  stopped=0
  for _ in $(seq 1 600); do
    kill -0 "$SERVER_PID" 2>/dev/null || { stopped=1; break; }
    sleep 0.1
  done
  STOP_S=$(( $(now) - T_STOP ))
  rc=0; wait "$SERVER_PID" || rc=$?
  SERVER_PID=""
  check "server stops on SIGTERM within 60 s (${STOP_S} s, exit $rc)" test "$stopped" -eq 1 -a "$rc" -eq 0
  # The run kept its session open (--keep-session): the shutdown persisted it.
  check "shutdown persisted the open session to the state volume" \
    test -n "$(buildah run --isolation chroot "$C" -- ls -A /var/lib/twistslam)"
  # Restart on the same state: the server comes back SERVING with it.
  buildah run --isolation chroot "$C" -- /usr/local/bin/twistslam-server \
    --listen 127.0.0.1:0 --state-dir /var/lib/twistslam --config /etc/twistslam/server.yaml \
    >"$WORK/server2.out" 2>"$WORK/server2.err" </dev/null &
  SERVER_PID=$!
  ADDR2=""
  for _ in $(seq 1 600); do
    line=$(head -n 1 "$WORK/server2.out" 2>/dev/null || true)
    if [[ "$line" == "listening on "* ]]; then ADDR2=${line#listening on }; break; fi
    kill -0 "$SERVER_PID" 2>/dev/null || break
    sleep 0.1
  done
  check "server restarts on the persisted state and serves" \
    buildah run --isolation chroot "$C2" -- /usr/local/bin/twistslam-health-probe \
      --addr "${ADDR2:-127.0.0.1:1}" --wait-ms 30000
else
  bad "server process found inside the container"
fi

log "timings: image build ${BUILD_S} s, end-to-end ${E2E_S} s, total $(( $(now) - T0 )) s"
echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ]
