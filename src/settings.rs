//! The settings a person chooses for a run, one home for the CLI's flags and the
//! page's settings panel: every field is optional (absent: the default), `config`
//! turns them into the engine's `ReconstructConfig` and refuses a value out of range
//! by name, and `tiling` into the tile plan asked for. The CLI and the page differ
//! only in their defaults for the grid (`Defaults`).

use crate::bundle::Manifest;
use crate::init::InitMethod;
use crate::reconstruct::ReconstructConfig;
use crate::tiles::{TileConfig, DEFAULT_OVERLAP_M};
use serde::{Deserialize, Serialize};

/// Every setting that changes the map (the page sends them as one object).
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct Settings {
    /// Grid spacing, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub resolution: Option<f64>,
    /// Corridor half-width, metres (absent: the bundle's, else the default's).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub half_width: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub epochs: Option<usize>,
    /// Use the bundle's LiDAR (elevation loss and refinement cue); default true.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lidar: Option<bool>,
    /// Align the poses to the LiDAR; default true.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub align: Option<bool>,
    /// Road-structure-aware refinement; default true.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adaptive: Option<bool>,
    /// "consensus" (default) or "nearest".
    #[serde(skip_serializing_if = "Option::is_none")]
    pub init: Option<String>,
    /// The trajectory-prior loss L_traj; default: on where the LiDAR term is off
    /// (no LiDAR in the bundle, or `lidar` false), off where it is on (with aligned
    /// LiDAR the prior pulls heights toward the poses' plane, the less accurate of
    /// the two: docs/QUALITY.md, ablation).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub traj_loss: Option<bool>,
    /// Hold out every K-th frame and report road PSNR on them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub holdout_every: Option<usize>,
    /// "ipm": write the IPM baseline instead of optimising.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub baseline: Option<String>,
    /// z learning rate at the start and the end, as ratios of the scene extent.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lr_z_start: Option<f32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lr_z_end: Option<f32>,
    /// LiDAR gate and band of the elevation loss, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lidar_gate: Option<f32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lidar_band: Option<f32>,
    /// Stop after this many steps.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_steps: Option<usize>,
    /// Seed of the training image order.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// Tile side, metres (absent or 0: untiled unless the drive is large).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tile_m: Option<f64>,
    /// Overlap of each tile beyond its square, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tile_overlap_m: Option<f64>,
    /// Up axis of the exported PLY files: "z" (world) or "y" (splat viewers).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ply_up: Option<String>,
    /// Fault injection for tests: the tile of this plan index fails at its first
    /// step as a lost device would.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fault_tile: Option<usize>,
    /// Photometric pose refinement (`optim::pose`); default false.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub refine_poses: Option<bool>,
    /// Its learning rates: metres and degrees per step.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pose_lr_m: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pose_lr_deg: Option<f64>,
    /// Fraction of the steps before the poses start to move (0 to 1).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pose_start: Option<f64>,
    /// Refine x, y and yaw only; default: when the poses are aligned to the LiDAR.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pose_planar: Option<bool>,
    /// Also refine each camera's mounting on the vehicle (rig offsets).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pose_rig: Option<bool>,
    /// Host memory the map's whole layers may take, MiB (default: 8 GiB).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub map_memory_mib: Option<u64>,
    /// Where files are written, when a tiled map is finished block by block:
    /// "auto" (default: over 1 GiB of whole layers or the budget), "blocks"
    /// (always) or "whole" (only over the budget).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub map_finish: Option<String>,
    /// "dense" (default: a step updates every surfel) or "selective" (only the
    /// surfels its view may see).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adam: Option<String>,
    /// Robust weighting scale of the RGB term (`LossConfig::robust_c`; 0, the
    /// default, disables it; docs/QUALITY.md says what it costs on parked cars).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub robust_c: Option<f32>,
    /// Start training from the colours on the LiDAR surface (`TrainConfig::
    /// lidar_colours`; default true).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lidar_colours: Option<bool>,
    /// A gain per frame on top of each camera's exposure (`TrainConfig::
    /// frame_exposure`; default true).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frame_exposure: Option<bool>,
    /// Learning rates by name (`LearningRates::set`: "rgb", "logits", "opacity", …),
    /// over the defaults.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub lr: Vec<(String, f32)>,
}

/// What a front end uses where a setting is absent.
#[derive(Clone, Copy, Debug)]
pub struct Defaults {
    pub resolution: f64,
    /// When the bundle gives no `corridor_half_width_m` either.
    pub half_width: f64,
}

/// The CLI's: the paper's 5 cm grid.
pub const CLI: Defaults = Defaults {
    resolution: 0.05,
    half_width: 8.0,
};
/// The page's: 10 cm, so that the demo runs in a minute or two on a CPU.
pub const PAGE: Defaults = Defaults {
    resolution: 0.1,
    half_width: 4.0,
};

fn positive<T: PartialOrd + Default + Copy + std::fmt::Display>(
    name: &str,
    v: Option<T>,
    example: &str,
) -> Result<Option<T>, String> {
    match v {
        Some(x) if x.partial_cmp(&T::default()) != Some(std::cmp::Ordering::Greater) => Err(
            format!("{name} {x}: expected a positive number, such as {example}"),
        ),
        _ => Ok(v),
    }
}

impl Settings {
    /// The engine's configuration for a run on the bundle of manifest `m`.
    pub fn config(&self, m: &Manifest, d: Defaults) -> Result<ReconstructConfig, String> {
        let mut c = ReconstructConfig::default();
        let res = positive("resolution", self.resolution, "0.05 (metres)")?;
        let hw = positive("half_width", self.half_width, "8 (metres)")?;
        if res.is_some_and(|r| !r.is_finite()) || hw.is_some_and(|h| !h.is_finite()) {
            return Err("resolution and half_width must be finite numbers of metres".into());
        }
        c.prepare.grid.resolution = res.unwrap_or(d.resolution);
        c.prepare.grid.half_width = hw.or(m.corridor_half_width_m).unwrap_or(d.half_width);
        c.prepare.refine.enabled = self.adaptive.unwrap_or(true);
        let lidar = self.lidar.unwrap_or(true);
        c.prepare.use_lidar = lidar;
        c.train.use_lidar = lidar;
        c.prepare.init.method = match self.init.as_deref() {
            None | Some("consensus") => InitMethod::Consensus,
            Some("nearest") => InitMethod::Nearest,
            Some(o) => return Err(format!("init {o:?}: expected \"consensus\" or \"nearest\"")),
        };
        if let Some(e) = self.epochs {
            if e == 0 {
                return Err("epochs 0: expected 1 or more passes over the images".into());
            }
            c.train.epochs = e;
        }
        if let Some(s) = self.seed {
            c.train.seed = s;
        }
        c.train.max_steps = positive("max_steps", self.max_steps, "100")?;
        c.train.holdout_every = self.holdout_every.filter(|&k| k > 0);
        if !self.traj_loss.unwrap_or(!(lidar && m.lidar.is_some())) {
            c.train.loss.traj = 0.0;
        }
        c.baseline_ipm = match self.baseline.as_deref() {
            None => false,
            Some("ipm") => true,
            Some(o) => return Err(format!("baseline {o:?}: expected \"ipm\"")),
        };
        let finite = |name: &str, v: Option<f32>, ex: &str| match positive(name, v, ex)? {
            Some(x) if !x.is_finite() => Err(format!("{name}: expected a finite number")),
            o => Ok(o),
        };
        if let Some(v) = finite("lidar_gate", self.lidar_gate, "0.5 (metres)")? {
            c.train.loss.lidar_gate_m = v;
        }
        if let Some(v) = finite("lidar_band", self.lidar_band, "0.2 (metres)")? {
            c.train.loss.lidar_band_m = v;
        }
        if let Some(v) = finite("lr_z_start", self.lr_z_start, "1.6e-3")? {
            c.train.lr.z_start = v;
        }
        if let Some(v) = finite("lr_z_end", self.lr_z_end, "1.6e-5")? {
            c.train.lr.z_end = v;
        }
        c.train.loss.robust_c = match self.robust_c {
            Some(r) if !(r.is_finite() && r >= 0.0) => {
                return Err(format!(
                    "robust_c {r}: expected 0 (off) or a positive colour residual, such as 0.1"
                ))
            }
            Some(r) => r,
            None => 0.0,
        };
        for (name, v) in &self.lr {
            c.train.lr.set(name, *v)?;
        }
        c.train.lr.check()?;
        if let Some(v) = self.lidar_colours {
            c.train.lidar_colours = v;
        }
        if let Some(v) = self.frame_exposure {
            c.train.frame_exposure = v;
        }
        if let Some(a) = self.adam.as_deref() {
            c.train.adam = crate::optim::AdamScope::parse(a)
                .ok_or_else(|| format!("adam {a:?}: expected \"dense\" or \"selective\""))?;
        }
        if self.align == Some(false) {
            c.align = None;
        }
        if self.refine_poses == Some(true) {
            let mut p = crate::optim::pose::PoseConfig::default();
            let num = |name: &str, v: Option<f64>, ex: &str| match positive(name, v, ex)? {
                Some(x) if !x.is_finite() => Err(format!("{name}: expected a finite number")),
                o => Ok(o),
            };
            if let Some(v) = num("pose_lr_m", self.pose_lr_m, "0.005 (metres per step)")? {
                p.lr_translation_m = v;
            }
            if let Some(v) = num("pose_lr_deg", self.pose_lr_deg, "0.05 (degrees per step)")? {
                p.lr_rotation_deg = v;
            }
            match self.pose_start {
                Some(v) if !(0.0..1.0).contains(&v) => {
                    return Err(format!(
                        "pose_start {v}: expected a fraction of the steps from 0 up to (not including) 1, such as 0.25"
                    ))
                }
                Some(v) => p.start = v,
                None => {}
            }
            // Where the LiDAR alignment fixes height, roll and pitch, the images
            // refine what it cannot see.
            let aligned = c.align.is_some() && lidar && m.lidar.is_some();
            p.planar = self.pose_planar.unwrap_or(aligned);
            p.rig = self.pose_rig.unwrap_or(false);
            c.poses = Some(p);
        }
        c.map.budget_bytes =
            positive("map_memory_mib", self.map_memory_mib, "8192")?.map(|m| m << 20);
        if let Some(f) = self.map_finish.as_deref() {
            c.map.finish = crate::reconstruct::MapFinish::parse(f).ok_or_else(|| {
                format!("map_finish {f:?}: expected \"auto\", \"blocks\" or \"whole\"")
            })?;
        }
        Ok(c)
    }

    /// The tiling asked for (`None`: let `tiles::choose` decide).
    pub fn tiling(&self) -> Result<Option<TileConfig>, String> {
        let overlap_m = match self.tile_overlap_m {
            Some(o) if !(o.is_finite() && o >= 0.0) => {
                return Err(format!(
                    "tile_overlap_m {o}: expected a number of metres, 0 or more, such as 4"
                ))
            }
            o => o.unwrap_or(DEFAULT_OVERLAP_M),
        };
        match self.tile_m {
            None => Ok(None),
            Some(0.0) => Ok(None),
            Some(v) if v.is_finite() && v > 0.0 => Ok(Some(TileConfig {
                size_m: v,
                overlap_m,
                origin_m: None,
            })),
            Some(v) => Err(format!(
                "tile size {v} m: expected a positive number of metres, such as 64"
            )),
        }
    }

    /// The PLY up axis asked for (default z).
    pub fn ply_up(&self) -> Result<crate::export::ply::Up, String> {
        match self.ply_up.as_deref() {
            None => Ok(crate::export::ply::Up::Z),
            Some(u) => u.parse().map_err(|e| format!("ply_up: {e}")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_map_to_the_config_and_bad_values_are_named() {
        let (m, _) = crate::bundle::example::tiny();
        let s: Settings = serde_json::from_str(
            r#"{"resolution": 0.2, "seed": 5, "max_steps": 12, "traj_loss": false,
                "lidar_gate": 0.7, "lr_z_start": 0.002, "baseline": "ipm", "tile_m": 24,
                "frame_exposure": false,
                "lr": [["rgb", 0.004], ["logits", 0.05]]}"#,
        )
        .expect("settings");
        let c = s.config(&m, PAGE).expect("config");
        assert_eq!(c.prepare.grid.resolution, 0.2);
        assert_eq!((c.train.seed, c.train.max_steps), (5, Some(12)));
        assert_eq!(c.train.loss.traj, 0.0);
        assert_eq!(c.train.loss.lidar_gate_m, 0.7);
        assert_eq!(c.train.lr.z_start, 0.002);
        assert_eq!((c.train.lr.rgb, c.train.lr.logits), (0.004, 0.05));
        assert!(c.baseline_ipm);
        assert!(!c.train.frame_exposure);
        let t = s.tiling().expect("tiling").expect("tiled");
        assert_eq!((t.size_m, t.overlap_m), (24.0, DEFAULT_OVERLAP_M));
        // Defaults: the front end's grid, the bundle's corridor when it has one.
        let c = Settings::default().config(&m, CLI).expect("config");
        assert_eq!(c.prepare.grid.resolution, 0.05);
        assert!(c.train.frame_exposure, "frame gains by default");
        let want = m.corridor_half_width_m.unwrap_or(CLI.half_width);
        assert_eq!(c.prepare.grid.half_width, want);
        for (json, says) in [
            (
                r#"{"lr_z_start": 0}"#,
                "lr_z_start 0: expected a positive number",
            ),
            (r#"{"resolution": -1}"#, "resolution -1"),
            (r#"{"init": "best"}"#, "init \"best\""),
            (r#"{"epochs": 0}"#, "epochs 0"),
            (r#"{"baseline": "rome"}"#, "baseline \"rome\""),
            (
                r#"{"refine_poses": true, "pose_start": 1.5}"#,
                "pose_start 1.5",
            ),
            (r#"{"refine_poses": true, "pose_lr_m": 0}"#, "pose_lr_m 0"),
            (
                r#"{"lr": [["colour", 0.1]]}"#,
                "no learning rate is called \"colour\"",
            ),
            (r#"{"lr": [["rgb", -1]]}"#, "the rgb learning rate is -1"),
        ] {
            let s: Settings = serde_json::from_str(json).expect("settings");
            let e = s.config(&m, PAGE).expect_err(json);
            assert!(e.contains(says), "{json}: {e}");
        }
        let s: Settings = serde_json::from_str(r#"{"tile_m": -3}"#).expect("settings");
        assert!(s.tiling().expect_err("tile").contains("tile size -3"));
        // A misspelled setting is refused, not ignored.
        let e = serde_json::from_str::<Settings>(r#"{"resolutoin": 0.1}"#).expect_err("typo");
        assert!(e.to_string().contains("resolutoin"), "{e}");
    }

    #[test]
    fn the_trajectory_prior_is_on_by_default_only_where_the_lidar_term_is_off() {
        let (m, _) = crate::bundle::example::tiny();
        assert!(m.lidar.is_some());
        let traj = |json: &str, m: &Manifest| {
            let s: Settings = serde_json::from_str(json).expect("settings");
            s.config(m, CLI).expect("config").train.loss.traj
        };
        let on = crate::loss::LossConfig::default().traj;
        assert!(on > 0.0);
        assert_eq!(traj("{}", &m), 0.0);
        assert_eq!(traj(r#"{"lidar": false}"#, &m), on);
        assert_eq!(traj(r#"{"traj_loss": true}"#, &m), on);
        assert_eq!(traj(r#"{"lidar": false, "traj_loss": false}"#, &m), 0.0);
        let mut without = m.clone();
        without.lidar = None;
        assert_eq!(traj("{}", &without), on);
    }
}
