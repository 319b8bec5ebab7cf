#!/usr/bin/env bash
# The pose-noise curve of docs/QUALITY.md: `demo` (LiDAR, seed 1) with pose noise of
# 0, 2.5, 5, 10 and 20 cm (and a tenth of that in degrees) per axis, mapped at 5 cm
# four ways: the IPM baseline, the default (one epoch), three epochs, and three
# epochs with pose refinement. Writes DIR/pose-noise.json (the figures of each run's
# report.json) for scripts/plot-scaling.py.
#
#   bash scripts/pose-noise-curve.sh DIR [ROGS]
set -euo pipefail
dir=${1:?usage: pose-noise-curve.sh DIR [ROGS binary]}
rogs=${2:-target/release/rogs}
mkdir -p "$dir"
for cm in 0 2.5 5 10 20; do
  m=$(python3 -c "print($cm / 100)")
  deg=$(python3 -c "print($cm / 10)")
  b="$dir/demo_$cm.zip"
  [ -f "$b" ] || "$rogs" synth --preset demo --lidar --seed 1 --pose-noise-m "$m" --pose-noise-deg "$deg" --out "$b"
  "$rogs" reconstruct "$b" --out "$dir/ipm_$cm" --half-width 4 --baseline ipm
  "$rogs" reconstruct "$b" --out "$dir/e1_$cm" --half-width 4
  "$rogs" reconstruct "$b" --out "$dir/e3_$cm" --half-width 4 --epochs 3
  "$rogs" reconstruct "$b" --out "$dir/e3r_$cm" --half-width 4 --epochs 3 --refine-poses
done 2> "$dir/log.txt"
python3 - "$dir" <<'EOF'
import json, sys, os
d = sys.argv[1]
names = {"ipm": "IPM baseline", "e1": "1 epoch", "e3": "3 epochs", "e3r": "3 epochs, refined"}
runs = []
for cm in ["0", "2.5", "5", "10", "20"]:
    for k, name in names.items():
        r = json.load(open(os.path.join(d, f"{k}_{cm}", "report.json")))
        m = r.get("metrics") or {}
        v = m.get("vs_reference") or {}
        p = (r.get("pose_refinement") or {}).get("error_after") or {}
        runs.append({
            "noise_cm": float(cm), "run": name,
            "psnr_db": m.get("psnr_db"), "miou": m.get("miou"),
            "elevation_rmse_cm": 100 * m["elevation_rmse_m"] if m.get("elevation_rmse_m") is not None else None,
            "elevation_datum_free_cm": 100 * m["elevation_datum"]["rmse_m"] if m.get("elevation_datum") else None,
            "initial_elevation_rmse_cm": 100 * m["initial_elevation_rmse_m"] if m.get("initial_elevation_rmse_m") is not None else None,
            "map_psnr_ref_cells_db": v.get("map_psnr_db"), "map_miou_ref_cells": v.get("map_miou"),
            "ref_psnr_db": v.get("ref_psnr_db"), "ref_miou": v.get("ref_miou"), "ref_cells": v.get("cells"),
            "train_s": (r.get("timings") or {}).get("train_ms", 0) / 1e3,
            "yaw_after_deg": p.get("yaw_deg"), "xy_centred_after_cm": 100 * p["xy_centred_m"] if p.get("xy_centred_m") is not None else None,
        })
out = {
    "source": "docs/QUALITY.md, pose-noise curve (scripts/pose-noise-curve.sh: demo, LiDAR, seed 1, 5 cm grid, release build, lavapipe)",
    "x": ["noise_cm", "pose noise per axis (cm; a tenth in °)"],
    "panels": [["psnr_db", "BEV PSNR (dB)"], ["miou", "mIoU"], ["elevation_rmse_cm", "elevation RMSE (cm)"]],
    "lines": {"IPM baseline": "#7570b3", "1 epoch": "#d95f02", "3 epochs": "#e6ab02", "3 epochs, refined": "#1b9e77"},
    "runs": runs,
}
json.dump(out, open(os.path.join(d, "pose-noise.json"), "w"), indent=1)
print(json.dumps(out["runs"], indent=None)[:4000])
EOF
