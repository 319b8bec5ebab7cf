#!/usr/bin/env bash
# The distributed path measured against the single-process run, on one drive:
#   bash scripts/bench-ray.sh [FRAMES] [TILE_M] [RESOLUTION]   (defaults 104 24 0.1)
# A `demo` drive lengthened to FRAMES metres (3 cameras, LiDAR) is mapped four ways,
# one after the other: one process (rogs reconstruct --tile-m), the plan's jobs one
# process each then rogs merge, and scripts/ray_map.py on a local Ray cluster with 1
# and with 2 workers. Prints wall times and the figures of the scaling model
# (docs/DISTRIBUTED.md). Needs a release build and .venv (scripts/setup.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/env.sh
frames="${1:-104}"; tile="${2:-24}"; res="${3:-0.1}"
R="$PWD/target/release/rogs"
W="$(mktemp -d "${TMPDIR:-/tmp}/rogs-bench-ray-XXXXXX")"
S=(--half-width 4 --resolution "$res" --tile-m "$tile")
now() { date +%s.%N; }
secs() { python3 -c "print(f'{$2 - $1:.1f}')"; }

"$R" synth --preset demo --lidar --frames "$frames" --rays-per-axis 1 --out "$W/d.zip" 2>/dev/null

t0=$(now); "$R" reconstruct "$W/d.zip" --out "$W/single" "${S[@]}" 2>/dev/null; t1=$(now)
single=$(secs "$t0" "$t1")

t0=$(now); "$R" plan "$W/d.zip" --out "$W/plan" "${S[@]}" 2>/dev/null; t1=$(now)
plan=$(secs "$t0" "$t1")
tiles=$(python3 -c "import json;print(' '.join(j['tile'] for j in json.load(open('$W/plan/plan.json'))['jobs']))")
t0=$(now)
for n in $tiles; do "$R" reconstruct --plan "$W/plan" --tile "$n" --out "$W/tiles/$n" 2>/dev/null; done
t1=$(now); "$R" merge "$W/plan" "$W/tiles" --out "$W/merged" 2>/dev/null; t2=$(now)
jobs=$(secs "$t0" "$t1"); merge=$(secs "$t1" "$t2")

ray() {
  local t0 t1
  t0=$(now)
  .venv/bin/python scripts/ray_map.py "$W/plan" --tiles "$W/rt$1" --out "$W/rm$1" --workers "$1" --rogs "$R" 2>/dev/null
  t1=$(now)
  secs "$t0" "$t1"
}
ray1=$(ray 1); ray2=$(ray 2)

python3 - "$W" "$single" "$plan" "$jobs" "$merge" "$ray1" "$ray2" <<'EOF'
import json, sys, statistics
w, single, plan, jobs, merge, ray1, ray2 = sys.argv[1], *map(float, sys.argv[2:])
per = [json.load(open(f"{w}/tiles/{j['tile']}/job.json"))["seconds"] for j in json.load(open(f"{w}/plan/plan.json"))["jobs"]]
rep = json.load(open(f"{w}/single/report.json"))
print(json.dumps({
    "tiles": len(per), "single_process_s": single, "plan_s": plan,
    "jobs_sequential_s": jobs, "merge_s": merge,
    "per_tile_s": {"mean": statistics.mean(per), "min": min(per), "max": max(per)},
    "ray_1_worker_s": ray1, "ray_2_workers_s": ray2,
    "ray1_summary": json.load(open(f"{w}/rm1/ray.json")),
    "single_psnr_db": rep["metrics"]["psnr_db"],
    "merged_psnr_db": json.load(open(f"{w}/merged/report.json"))["metrics"]["psnr_db"],
}, indent=1))
EOF
rm -rf "$W"
