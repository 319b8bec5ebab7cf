#!/usr/bin/env bash
# Peak resident memory and wall time of a tiled map finished with its whole layers
# held and block by block (docs/PERFORMANCE.md, "The finish block by block"): for
# each length L, the IPM baseline (no training) of `highway` L metres long at 5 cm.
#   bash scripts/bench-finish.sh DIR L [L ...]   (TILE=32 sets the tile size, m)
# DIR holds hwL.zip (made if missing: rogs synth --preset highway --length-m L
# --rays-per-axis 1) and receives each run's output folder and log.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
rogs="$root/target/release/rogs"
dir="$1"
shift
mkdir -p "$dir"
cd "$dir"
for L in "$@"; do
  [ -f "hw$L.zip" ] || "$rogs" synth --preset highway --length-m "$L" --rays-per-axis 1 --out "hw$L.zip"
  for F in whole blocks; do
    rm -rf "o-$L-$F"
    /usr/bin/time -v "$rogs" reconstruct "hw$L.zip" --out "o-$L-$F" --resolution 0.05 \
      --baseline ipm --tile-m "${TILE:-96}" --finish "$F" > "r-$L-$F.log" 2>&1
    rss=$(grep "Maximum resident" "r-$L-$F.log" | awk '{print $6}')
    wall=$(grep "Elapsed" "r-$L-$F.log" | awk '{print $8}')
    python3 - "$L" "$F" "$rss" "$wall" <<'P'
import json, sys
L, F, rss, wall = sys.argv[1:]
r = json.load(open(f"o-{L}-{F}/report.json"))
b = json.load(open(f"o-{L}-{F}/bev.json"))
print(f"{L} m, finish {F}: {b['width']}x{b['height']} px, process peak {int(rss) >> 10} MiB, "
      f"peak while training {r['peak_host_training_bytes'] >> 20} MiB, wall {wall}, "
      f"finish {r['timings']['eval_ms'] / 1e3:.1f} s, PSNR {r['metrics']['psnr_db']:.9f} dB, "
      f"layers {r.get('map_layers')}")
P
  done
done
