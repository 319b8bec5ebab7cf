//! What `rogs inspect` and the page show about a valid bundle.

use super::manifest::{ClassRole, Manifest};
use super::source::Source;
use serde::Serialize;

#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub name: String,
    pub cameras: Vec<CameraSummary>,
    pub frames: usize,
    pub views: usize,
    pub duration_s: f64,
    pub trajectory_length_m: f64,
    pub classes: Vec<ClassSummary>,
    /// Whether the views carry label images (false: a drive without masks).
    pub labelled: bool,
    /// Logit channels a map of this bundle has: one per class, one (the road
    /// surface) without labels.
    pub channels: usize,
    /// Total LiDAR points over all sweeps (0 without LiDAR).
    pub lidar_points: u64,
    pub lidar_sweeps: usize,
    pub ground_truth: Option<GroundTruthSummary>,
    /// The bundle's corridor half-width, metres (its `corridor_half_width_m`).
    pub corridor_half_width_m: Option<f64>,
    /// The dataset frame the poses are in, in words (none: a local frame).
    pub world_frame: Option<String>,
    /// Things the bundle holds that rogs ignores (e.g. a misspelled optional field).
    pub warnings: Vec<String>,
}

#[derive(Clone, Debug, Serialize)]
pub struct CameraSummary {
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct ClassSummary {
    pub id: u8,
    pub name: String,
    pub color: [u8; 3],
    pub role: ClassRole,
}

#[derive(Clone, Debug, Serialize)]
pub struct GroundTruthSummary {
    pub width: u32,
    pub height: u32,
    pub resolution_m: f64,
}

impl Summary {
    pub fn of(m: &Manifest, source: &dyn Source) -> Self {
        let stride = m
            .lidar
            .as_ref()
            .map_or(12, |l| 4 * l.floats_per_point as u64);
        let sweeps: Vec<&String> = m.frames.iter().filter_map(|f| f.lidar.as_ref()).collect();
        let lidar_points = sweeps
            .iter()
            .filter_map(|p| source.size(p))
            .map(|len| len / stride)
            .sum();
        let duration_s = match (m.frames.first(), m.frames.last()) {
            (Some(a), Some(b)) => b.timestamp - a.timestamp,
            _ => 0.0,
        };
        Self {
            name: m.name.clone(),
            cameras: m
                .cameras
                .iter()
                .map(|c| CameraSummary {
                    name: c.name.clone(),
                    width: c.width,
                    height: c.height,
                    fx: c.fx,
                    fy: c.fy,
                })
                .collect(),
            frames: m.frames.len(),
            views: m.frames.iter().map(|f| f.views.len()).sum(),
            duration_s,
            trajectory_length_m: m.trajectory_length_m(),
            classes: m
                .semantic_classes
                .iter()
                .map(|c| ClassSummary {
                    id: c.id,
                    name: c.name.clone(),
                    color: c.color,
                    role: c.role,
                })
                .collect(),
            labelled: m.labelled(),
            channels: m.classes().len().max(1),
            lidar_points,
            lidar_sweeps: sweeps.len(),
            ground_truth: m.ground_truth.as_ref().map(|g| GroundTruthSummary {
                width: g.width,
                height: g.height,
                resolution_m: g.resolution,
            }),
            corridor_half_width_m: m.corridor_half_width_m,
            world_frame: m.world_frame.as_ref().map(|_| m.frame_description()),
            warnings: Vec::new(),
        }
    }

    /// Plain-text rendering for the terminal.
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        let name = if self.name.is_empty() {
            "(unnamed)"
        } else {
            &self.name
        };
        s += &format!("bundle      {name}\n");
        s += &format!(
            "frames      {} ({} views, {:.1} s)\n",
            self.frames, self.views, self.duration_s
        );
        s += &format!("trajectory  {:.1} m\n", self.trajectory_length_m);
        s += &format!("cameras     {}\n", self.cameras.len());
        for c in &self.cameras {
            s += &format!(
                "  {:<12} {}×{}  fx {:.1} fy {:.1}\n",
                c.name, c.width, c.height, c.fx, c.fy
            );
        }
        s += &format!("classes     {}\n", self.classes.len());
        for c in &self.classes {
            let role = match c.role {
                ClassRole::Road => "road",
                ClassRole::Ignore => "ignore",
            };
            s += &format!("  {:>3} {:<16} {role}\n", c.id, c.name);
        }
        if !self.labelled {
            s += "labels      none: a drive without masks (the road plane below each camera's \
                  horizon is supervised; the map has no semantic layer)\n";
        }
        s += &format!(
            "lidar       {} points in {} sweeps\n",
            self.lidar_points, self.lidar_sweeps
        );
        match &self.ground_truth {
            Some(g) => {
                s += &format!(
                    "truth       BEV {}×{} at {} m\n",
                    g.width, g.height, g.resolution_m
                )
            }
            None => s += "truth       none\n",
        }
        for w in &self.warnings {
            s += &format!("warning     {w}\n");
        }
        s
    }
}
