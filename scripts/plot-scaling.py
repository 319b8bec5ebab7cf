#!/usr/bin/env python3
"""Plots figures of runs as lines, one panel per figure, one line per kind of run,
as an SVG:

    python3 scripts/plot-scaling.py docs/data/tiles-scaling.json docs/images/tiles-scaling.svg
    python3 scripts/plot-scaling.py docs/data/pose-noise.json docs/images/pose-noise.svg

The data file lists runs, {"runs": [{"length_m", "run": "untiled"|"tiled", "wall_s",
"peak_gpu_mib", "peak_host_mib"}, …]} by default (docs/PERFORMANCE.md, "Tiles: time
and memory against drive length"); it may name its own axes: "x": [key, title],
"panels": [[key, title], …], "lines": {run: colour, …}. No plotting library: the SVG
is written by hand, so the script runs with any Python 3.
"""

import json
import sys

W, H = 900, 330
PANEL_W, PANEL_H = 240, 220
COLOURS = {"untiled": "#d95f02", "tiled": "#1b9e77"}
PANELS = [("wall_s", "wall time (s)"), ("peak_host_mib", "peak host memory (MiB)"), ("peak_gpu_mib", "peak GPU reserved (MiB)")]
X = ("length_m", "drive length (m)")


def nice_max(v):
    for exp in range(0, 9):
        for step in (1, 2, 2.5, 5):
            m = step * 10 ** exp
            if m >= v:
                return m
    return v


def main(src, dst):
    with open(src) as f:
        data = json.load(f)
    runs = data["runs"]
    xkey, xtitle = data.get("x", X)
    panels = data.get("panels", PANELS)
    colours = data.get("lines", COLOURS)
    xmax = nice_max(max(r[xkey] for r in runs))
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" font-size="12">',
           f'<rect width="{W}" height="{H}" fill="white"/>']
    for k, (key, title) in enumerate(panels):
        x0, y0 = 60 + k * 290, 40
        ymax = nice_max(max(r[key] for r in runs if r.get(key) is not None) * 1.05)
        sx = lambda v: x0 + v / xmax * PANEL_W
        sy = lambda v: y0 + PANEL_H - v / ymax * PANEL_H
        out.append(f'<text x="{x0 + PANEL_W / 2}" y="{y0 - 14}" text-anchor="middle" font-weight="bold">{title}</text>')
        out.append(f'<rect x="{x0}" y="{y0}" width="{PANEL_W}" height="{PANEL_H}" fill="none" stroke="#999"/>')
        for i in range(5):
            yv = ymax * i / 4
            out.append(f'<line x1="{x0 - 4}" y1="{sy(yv):.1f}" x2="{x0}" y2="{sy(yv):.1f}" stroke="#999"/>')
            out.append(f'<text x="{x0 - 6}" y="{sy(yv) + 4:.1f}" text-anchor="end">{yv:g}</text>')
            xv = xmax * i / 4
            out.append(f'<text x="{sx(xv):.1f}" y="{y0 + PANEL_H + 16}" text-anchor="middle">{xv:g}</text>')
        out.append(f'<text x="{x0 + PANEL_W / 2}" y="{y0 + PANEL_H + 32}" text-anchor="middle">{xtitle}</text>')
        for run, colour in colours.items():
            pts = sorted((r[xkey], r[key]) for r in runs if r["run"] == run and r.get(key) is not None)
            path = " ".join(f"{sx(x):.1f},{sy(y):.1f}" for x, y in pts)
            out.append(f'<polyline points="{path}" fill="none" stroke="{colour}" stroke-width="2"/>')
            for x, y in pts:
                out.append(f'<circle cx="{sx(x):.1f}" cy="{sy(y):.1f}" r="3.5" fill="{colour}"/>')
    for i, (run, colour) in enumerate(colours.items()):
        lx = W / 2 - 70 * len(colours) + i * 140
        out.append(f'<rect x="{lx}" y="{H - 22}" width="14" height="4" fill="{colour}"/>')
        out.append(f'<text x="{lx + 20}" y="{H - 16}">{run}</text>')
    out.append("</svg>")
    with open(dst, "w") as f:
        f.write("\n".join(out) + "\n")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
