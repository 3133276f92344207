#!/usr/bin/env bash
# The object figures of issue #5 over a set of rendered runs, in one command.
#
# For each scenario x seed: generates the sequence (kept in WORK/data and
# reused), runs it through the embedded engine (synchronous mapping unless
# --config says otherwise), evaluates it online and refined, and prints one
# line per run plus the mean over the runs of the moving cars' (class 26)
# figures and the parked cars' speed error and the camera's RPE_t, then where
# the moving cars' missed visible frames lie (summed over the runs); the same
# as JSON in WORK/sweep.json. This is how the tables of docs/objects.md are
# measured.
#
#   bench/objects/scenario_sweep.sh [--bin build/client/twistslam] [--work /tmp/sweep]
#       [--scenarios "driving follow_braking intersection stationary_then_accelerating turning_traffic"]
#       [--seeds "1 2 3 4 5 6"] [--frames 100] [--jobs 2] [--config FILE] [--label NAME]
#       [--realtime]
#
# The default scenarios are every generator scenario with moving cars
# (docs/sim.md), as issue #5 asks. --realtime sends the frames at 10 Hz, as a
# live camera would (use --jobs 1 then, and a --config with
# `slam: {mapping_mode: background}` for the service's mode).
#
# Runs with the same label reuse their outputs (delete WORK/runs/LABEL to run again).
set -euo pipefail

bin=build/client/twistslam
work=/tmp/sweep
scenarios="driving follow_braking intersection stationary_then_accelerating turning_traffic"
seeds="1 2 3 4 5 6"
frames=100
jobs=2
config=""
label=default
realtime=""
while [ $# -gt 0 ]; do
  case "$1" in
    --bin) bin=$2; shift 2 ;;
    --work) work=$2; shift 2 ;;
    --scenarios) scenarios=$2; shift 2 ;;
    --seeds) seeds=$2; shift 2 ;;
    --frames) frames=$2; shift 2 ;;
    --jobs) jobs=$2; shift 2 ;;
    --config) config=$2; shift 2 ;;
    --label) label=$2; shift 2 ;;
    --realtime) realtime=--realtime; shift ;;
    -h|--help) sed -n 2,23p "$0"; exit 0 ;;
    *) echo "scenario_sweep: unknown argument $1" >&2; exit 2 ;;
  esac
done
[ -x "$bin" ] || { echo "scenario_sweep: no executable at $bin (build first)" >&2; exit 2; }
bin=$(realpath "$bin")
[ -z "$config" ] || config=$(realpath "$config")
runs="$work/runs/$label"
mkdir -p "$work/data" "$runs"

one_run() {
  local scenario=$1 seed=$2
  local data="$work/data/${scenario}_${seed}_${frames}" out="$runs/${scenario}_${seed}"
  if [ ! -f "$data/.complete" ]; then
    rm -rf "$data"
    "$bin" generate --scenario "$scenario" --frames "$frames" --seed "$seed" --out "$data" >/dev/null
    touch "$data/.complete"
  fi
  if [ ! -f "$out/refined.json" ]; then
    rm -rf "$out"
    local cfg=()
    [ -z "$config" ] || cfg=(--config "$config")
    [ -z "$realtime" ] || cfg+=("$realtime")
    "$bin" run --embedded --dataset "$data" --format kitti-tracking --seq 0000 --out "$out" \
      "${cfg[@]}" >"$out.log" 2>&1 || { echo "run failed: $scenario $seed (see $out.log)" >&2; return 1; }
    "$bin" eval --dataset "$data" --format kitti-tracking --seq 0000 --est "$out" \
      --json "$out/online.json" >/dev/null
    "$bin" eval --dataset "$data" --format kitti-tracking --seq 0000 --est "$out" --refined \
      --json "$out/refined.json" >/dev/null
  fi
}
export -f one_run
export bin work runs frames config realtime

for scenario in $scenarios; do
  for seed in $seeds; do echo "$scenario $seed"; done
done | xargs -P "$jobs" -L 1 bash -c 'one_run "$0" "$1"'

python3 - "$runs" "$scenarios" "$seeds" "$work/sweep.json" <<'EOF'
import json, math, sys
runs, scenarios, seeds, out = sys.argv[1], sys.argv[2].split(), sys.argv[3].split(), sys.argv[4]

def cars(doc, moving):
    for c in (doc.get("objects") or {}).get("by_class", []):
        if c["class_id"] == 26 and c["moving"] == moving:
            return c["aggregate"]
    return None

def moving_cars(doc):
    return [o for o in ((doc.get("objects") or {}).get("per_object") or [])
            if o["class_id"] == 26 and o["moving"]]

keys = ["ate_m", "rpe_t_m_per_m", "rpe_r_deg_per_m", "speed_error_kmh", "visible_coverage"]
rows, sums, missed, visible = [], {}, {}, [0]
def add(name, v):
    if v is not None and isinstance(v, (int, float)) and math.isfinite(v):
        sums.setdefault(name, []).append(v)

print(f"{'run':34s} {'ATE m':>7s} {'RPE_t':>7s} {'RPE_R':>7s} {'speed':>6s} {'viscov':>6s}"
      f" {'frag':>4s} {'rATE':>7s} {'rRPE_R':>7s} {'parked':>6s} {'camRPEt':>8s}")
for sc in scenarios:
    for sd in seeds:
        d = f"{runs}/{sc}_{sd}"
        try:
            on = json.load(open(f"{d}/online.json"))
            ref = json.load(open(f"{d}/refined.json"))
        except OSError:
            print(f"{sc}_{sd}: missing outputs"); continue
        m, r, p = cars(on, True), cars(ref, True), cars(on, False)
        cam = (on.get("camera") or {}).get("rpe_t_m_per_frame")
        frag = sum(max(0, o["num_est_tracks"] - 1) for o in moving_cars(on))
        row = {"run": f"{sc}_{sd}", "online": m, "refined": r, "parked": p, "camera_rpe_t": cam,
               "fragments": frag}
        rows.append(row)
        f = lambda a, k: a[k] if a and a.get(k) is not None else float("nan")
        print(f"{sc+'_'+sd:34s} {f(m,'ate_m'):7.4f} {f(m,'rpe_t_m_per_m'):7.4f}"
              f" {f(m,'rpe_r_deg_per_m'):7.4f} {f(m,'speed_error_kmh'):6.3f}"
              f" {f(m,'visible_coverage'):6.3f} {frag:4d} {f(r,'ate_m'):7.4f}"
              f" {f(r,'rpe_r_deg_per_m'):7.4f} {f(p,'speed_error_kmh'):6.3f}"
              f" {cam if cam is not None else float('nan'):8.5f}")
        for k in keys:
            add("online." + k, m.get(k) if m else None)
            add("refined." + k, r.get(k) if r else None)
        add("parked.speed_error_kmh", p.get("speed_error_kmh") if p else None)
        add("camera.rpe_t_m_per_frame", cam)
        add("fragments", frag)
        for k, v in ((m or {}).get("visible_missed") or {}).items():
            missed[k] = missed.get(k, 0) + v
        visible[0] += sum(o.get("visible_gt_frames", 0) for o in moving_cars(on))
mean = {k: sum(v) / len(v) for k, v in sums.items()}
g = lambda k: mean.get(k, float("nan"))
print(f"mean over {len(rows)} runs: cars ATE {g('online.ate_m'):.4f} ({g('refined.ate_m'):.4f}) m,"
      f" RPE_t {g('online.rpe_t_m_per_m'):.4f} ({g('refined.rpe_t_m_per_m'):.4f}) m/m,"
      f" RPE_R {g('online.rpe_r_deg_per_m'):.4f} ({g('refined.rpe_r_deg_per_m'):.4f}) deg/m,"
      f" speed {g('online.speed_error_kmh'):.3f} ({g('refined.speed_error_kmh'):.3f}) km/h,"
      f" viscov {g('online.visible_coverage'):.3f}, fragments {g('fragments'):.2f},"
      f" parked {g('parked.speed_error_kmh'):.3f} km/h,"
      f" camera RPE_t {g('camera.rpe_t_m_per_frame'):.5f} m/frame")
if missed:
    print(f"moving cars' visible frames missed, of {visible[0]}: " +
          ", ".join(f"{k} {v}" for k, v in missed.items()) +
          " (docs/formats.md: visible_missed)")
json.dump({"runs": rows, "mean": mean, "visible_missed": missed}, open(out, "w"), indent=1)
EOF
