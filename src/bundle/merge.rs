//! Several drives of the same place as one bundle: `Bundle::merge` concatenates the
//! drives' frames into one manifest over one world frame, so that every later stage
//! (grid, tiles, training) sees one set of surfels trained by every drive's views.
//!
//! What stays per drive: each camera becomes its own camera per drive (`NAME#2` for
//! the second drive's), so exposure is learned per camera per drive; file paths are
//! routed to their drive's source by a `driveK/` prefix; the corridor is one polyline
//! per drive (`Bundle::drives`), never a segment from one drive's end to the next
//! drive's start. What must agree, or the merge is refused by name: the class table,
//! the vehicle height and the LiDAR calibration. Drives must overlap: each must pass
//! within `DRIVE_GAP_M` of another (bundles in different world frames, or of other
//! streets, are refused rather than mapped side by side).

use super::{Bundle, Drive, Limits, Manifest, Problem, Source};

/// Two drives overlap when one passes within this many metres (xy) of the other.
pub const DRIVE_GAP_M: f64 = 20.0;

/// Files of drive k live under `drive{k}/` in the merged bundle.
struct MergedSource {
    parts: Vec<Box<dyn Source>>,
}

impl MergedSource {
    fn route<'a>(&self, path: &'a str) -> Option<(&dyn Source, &'a str)> {
        let rest = path.strip_prefix("drive")?;
        let (k, rest) = rest.split_once('/')?;
        let k: usize = k.parse().ok()?;
        Some((self.parts.get(k)?.as_ref(), rest))
    }
}

impl Source for MergedSource {
    fn size(&self, path: &str) -> Option<u64> {
        let (s, p) = self.route(path)?;
        s.size(p)
    }

    fn read(&self, path: &str, limits: &Limits) -> Result<Vec<u8>, Problem> {
        match self.route(path) {
            Some((s, p)) => s.read(p, limits),
            None => Err(Problem::Unreadable {
                path: path.into(),
                reason: "not a file of any merged drive".into(),
            }),
        }
    }
}

fn invalid(field: String, what: String) -> Problem {
    Problem::Invalid { field, what }
}

fn same_rows(a: &super::Mat4Rows, b: &super::Mat4Rows) -> bool {
    a.iter()
        .flatten()
        .zip(b.iter().flatten())
        .all(|(x, y)| (x - y).abs() <= 1e-6)
}

/// Smallest xy distance between a frame of `a` and a frame of `b` (early exit below
/// `stop`).
fn gap(a: &Manifest, b: &Manifest, stop: f64) -> f64 {
    let xy = |m: &Manifest| -> Vec<[f64; 2]> {
        m.frames
            .iter()
            .map(|f| [f.vehicle_to_world[0][3], f.vehicle_to_world[1][3]])
            .collect()
    };
    let (pa, pb) = (xy(a), xy(b));
    let mut best = f64::INFINITY;
    for p in &pa {
        for q in &pb {
            best = best.min((p[0] - q[0]).hypot(p[1] - q[1]));
            if best < stop {
                return best;
            }
        }
    }
    best
}

impl Bundle {
    /// One bundle of several drives (`names` label them in errors: file names). A
    /// single bundle is returned as it is.
    pub fn merge(mut bundles: Vec<Bundle>, names: &[String]) -> Result<Bundle, Problem> {
        if bundles.len() <= 1 {
            return bundles.pop().ok_or_else(|| {
                invalid(
                    "bundles".into(),
                    "no bundle was given; expected one or more".into(),
                )
            });
        }
        let name = |k: usize| {
            names
                .get(k)
                .cloned()
                .unwrap_or_else(|| format!("bundle {}", k + 1))
        };
        // Drives in one dataset frame with different offsets (two nuScenes scenes of a
        // place, each shifted to its own first pose) are brought into the first's.
        let frame0 = bundles[0].manifest.world_frame.clone();
        for (k, b) in bundles.iter_mut().enumerate().skip(1) {
            let m = &mut b.manifest;
            match (&frame0, &m.world_frame) {
                (None, None) => {}
                (Some(f0), Some(f)) if f0.name == f.name => {
                    let d: [f64; 3] = [0, 1, 2].map(|i| f.offset_m[i] - f0.offset_m[i]);
                    for fr in &mut m.frames {
                        let views = fr
                            .views
                            .iter_mut()
                            .filter_map(|v| v.vehicle_to_world.as_mut());
                        for t in std::iter::once(&mut fr.vehicle_to_world).chain(views) {
                            for (i, di) in d.iter().enumerate() {
                                t[i][3] += di;
                            }
                        }
                    }
                    if let Some(g) = &mut m.ground_truth {
                        g.origin[0] += d[0];
                        g.origin[1] += d[1];
                    }
                    m.world_frame = frame0.clone();
                }
                (a, b) => {
                    let said = |f: &Option<super::WorldFrame>| {
                        f.as_ref()
                            .map_or("no world frame".to_string(), |f| format!("{:?}", f.name))
                    };
                    return Err(invalid(
                        format!("{}: world_frame", name(k)),
                        format!(
                            "is {}, {}'s is {}; drives of one map must be in one world frame",
                            said(b),
                            name(0),
                            said(a)
                        ),
                    ));
                }
            }
        }
        let first = bundles[0].manifest.clone();
        // Every drive must come within DRIVE_GAP_M of a drive already connected to
        // the first: one map of one place, not two maps side by side.
        let n = bundles.len();
        let mut linked = vec![false; n];
        linked[0] = true;
        let mut grew = true;
        while grew {
            grew = false;
            for k in 0..n {
                if linked[k] {
                    continue;
                }
                let near = (0..n).any(|j| {
                    linked[j]
                        && gap(&bundles[j].manifest, &bundles[k].manifest, DRIVE_GAP_M)
                            < DRIVE_GAP_M
                });
                if near {
                    linked[k] = true;
                    grew = true;
                }
            }
        }
        if let Some(k) = linked.iter().position(|l| !l) {
            let d = (0..n)
                .filter(|&j| j != k)
                .map(|j| gap(&bundles[j].manifest, &bundles[k].manifest, 0.0))
                .fold(f64::INFINITY, f64::min);
            return Err(invalid(
                format!("{}: frames", name(k)),
                format!(
                    "this drive does not overlap the others: its nearest pose is {d:.0} m from \
                     theirs (overlap needs {DRIVE_GAP_M} m or less); bundles merged into one map \
                     must share one world frame and cover some of the same streets"
                ),
            ));
        }
        let mut m = first.clone();
        m.name = bundles
            .iter()
            .map(|b| b.manifest.name.as_str())
            .collect::<Vec<_>>()
            .join(" + ");
        m.cameras.clear();
        m.frames.clear();
        m.ground_truth = None;
        let mut drives = Vec::new();
        let mut parts: Vec<Box<dyn Source>> = Vec::new();
        let mut warnings: Vec<String> = Vec::new();
        let mut limits = bundles[0].limits;
        for (k, b) in bundles.into_iter().enumerate() {
            let bm = &b.manifest;
            if bm.labelled() != first.labelled() {
                return Err(invalid(
                    format!("{}: frames[].views[].label", name(k)),
                    format!(
                        "{} labels and {} {}; drives of one map are all labelled or all \
                         without labels (rogs segment can label a drive)",
                        if bm.labelled() { "has" } else { "has no" },
                        name(0),
                        if first.labelled() { "has" } else { "has none" },
                    ),
                ));
            }
            if bm.semantic_classes != first.semantic_classes {
                return Err(invalid(
                    format!("{}: semantic_classes", name(k)),
                    format!(
                        "differs from {}'s class table; drives of one map need the same classes \
                         (ids, names, colours, roles)",
                        name(0)
                    ),
                ));
            }
            if (bm.vehicle_height_m - first.vehicle_height_m).abs() > 1e-3 {
                return Err(invalid(
                    format!("{}: vehicle_height_m", name(k)),
                    format!(
                        "is {} m, {}'s is {} m; drives of one map need one vehicle frame height",
                        bm.vehicle_height_m,
                        name(0),
                        first.vehicle_height_m
                    ),
                ));
            }
            match (&m.lidar, &bm.lidar) {
                (Some(a), Some(l))
                    if a.floats_per_point != l.floats_per_point
                        || !same_rows(&a.lidar_to_vehicle, &l.lidar_to_vehicle) =>
                {
                    return Err(invalid(
                        format!("{}: lidar", name(k)),
                        "differs from an earlier drive's LiDAR calibration; one map reads \
                         one LiDAR calibration (remove the sweeps of one drive to merge them)"
                            .into(),
                    ));
                }
                (None, Some(l)) => m.lidar = Some(l.clone()),
                _ => {}
            }
            let prefix = format!("drive{k}/");
            let rename = |c: &str| format!("{c}#{}", k + 1);
            for c in &bm.cameras {
                let mut c = c.clone();
                c.name = rename(&c.name);
                c.mask = c.mask.map(|p| format!("{prefix}{p}"));
                m.cameras.push(c);
            }
            let start = m.frames.len();
            for f in &bm.frames {
                let mut f = f.clone();
                for v in &mut f.views {
                    v.camera = rename(&v.camera);
                    v.image = format!("{prefix}{}", v.image);
                    v.label = v.label.as_ref().map(|l| format!("{prefix}{l}"));
                }
                f.lidar = f.lidar.map(|l| format!("{prefix}{l}"));
                m.frames.push(f);
            }
            if m.ground_truth.is_none() {
                m.ground_truth = bm.ground_truth.clone().map(|mut g| {
                    for p in [&mut g.rgb, &mut g.class_ids, &mut g.elevation, &mut g.valid] {
                        *p = format!("{prefix}{p}");
                    }
                    // One drive's exact poses do not number the merged frames.
                    g.poses = None;
                    g
                });
            }
            drives.push(Drive {
                name: name(k),
                frames: start..m.frames.len(),
            });
            limits = b.limits;
            warnings.extend(b.warnings.iter().map(|w| format!("{}: {w}", name(k))));
            parts.push(b.source);
        }
        Ok(Bundle {
            manifest: m,
            limits,
            drives,
            warnings,
            source: Box::new(MergedSource { parts }),
        })
    }
}
