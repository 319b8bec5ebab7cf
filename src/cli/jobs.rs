//! Tile jobs from the command line: `rogs plan` writes a reconstruction's tiles as
//! jobs, `rogs reconstruct --plan PLAN --tile NAME` runs one (`run_tile`), `rogs
//! merge` stitches their checkpoints into the map. A scheduler runs the jobs where it
//! likes (scripts/ray_map.py on a Ray cluster); docs/DISTRIBUTED.md.

use super::reconstruct::{open_bundles, start, train, write_map, SettingsArgs};
use super::{EXIT_INVALID_INPUT, EXIT_MACHINE};
use crate::tiles::checkpoint;
use crate::tiles::jobs::{checkpoint_path, PlanFile};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct PlanArgs {
    /// The scene bundles (.zip or folder), as for `rogs reconstruct`. Every job reads
    /// them from these paths: put them where every worker sees them (shared storage).
    #[arg(required = true, num_args = 1..)]
    bundles: Vec<PathBuf>,
    /// The plan's folder: plan.json and jobs/NAME.json (created if missing).
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    settings: SettingsArgs,
}

#[derive(clap::Args)]
pub struct MergeArgs {
    /// The plan's folder (made by `rogs plan`).
    plan: PathBuf,
    /// The folder of the tile jobs' outputs: TILES/NAME/NAME.tile for every tile.
    tiles: PathBuf,
    /// Output folder for the map, as `rogs reconstruct --out`.
    #[arg(long)]
    out: PathBuf,
    /// Up axis of surfels.ply and surfels_semantic.ply (as `rogs reconstruct`).
    #[arg(long, default_value = "z")]
    ply_up: crate::export::ply::Up,
}

/// Prints a bad-input problem and answers its exit code.
fn bad(msg: String) -> Result<ExitCode, String> {
    eprintln!("{msg}");
    Ok(ExitCode::from(EXIT_INVALID_INPUT))
}

pub fn plan(a: PlanArgs) -> Result<ExitCode, String> {
    // Absolute paths: jobs run from other folders and machines.
    let mut names = Vec::new();
    for p in &a.bundles {
        match std::path::absolute(p) {
            Ok(abs) => names.push(abs.display().to_string()),
            Err(e) => return bad(format!("{}: {e}", p.display())),
        }
    }
    let mut b = match open_bundles(&a.bundles) {
        Ok(b) => b,
        Err(code) => return Ok(code),
    };
    let s = a.settings.settings();
    let run = match start(&mut b, &s, true) {
        Ok(r) => r,
        Err(code) => return Ok(code),
    };
    let plan = PlanFile::of(&run, names, s)?;
    let jobs_dir = a.out.join("jobs");
    std::fs::create_dir_all(&jobs_dir)
        .map_err(|e| format!("cannot create {}: {e}", jobs_dir.display()))?;
    for k in 0..plan.jobs.len() {
        let Some(job) = plan.job(&run, k) else {
            continue;
        };
        let p = jobs_dir.join(format!("{}.json", job.tile));
        let bytes = serde_json::to_vec_pretty(&job).map_err(|e| e.to_string())?;
        std::fs::write(&p, bytes).map_err(|e| format!("cannot write {}: {e}", p.display()))?;
    }
    let p = a.out.join("plan.json");
    let bytes = serde_json::to_vec_pretty(&plan).map_err(|e| e.to_string())?;
    std::fs::write(&p, bytes).map_err(|e| format!("cannot write {}: {e}", p.display()))?;
    let d = a.out.display();
    eprintln!(
        "{} tile jobs of {} m, {} steps in all, written to {d}\n\
         run each:   rogs reconstruct --plan {d} --tile NAME --out TILES/NAME\n\
         then merge: rogs merge {d} TILES --out MAP\n\
         or both on a Ray cluster: python3 scripts/ray_map.py {d} --tiles TILES --out MAP",
        plan.jobs.len(),
        plan.tiling.size_m,
        plan.steps
    );
    Ok(ExitCode::SUCCESS)
}

/// Reads a plan folder's plan.json.
fn read_plan(dir: &Path) -> Result<PlanFile, String> {
    let p = dir.join("plan.json");
    let bytes = std::fs::read(&p).map_err(|e| {
        format!(
            "{}: {e} (a plan folder is made by `rogs plan BUNDLE… --out PLAN`)",
            p.display()
        )
    })?;
    PlanFile::parse(&bytes).map_err(|e| format!("{}: {e}", p.display()))
}

/// Opens the plan's bundles (paths relative to the plan's folder) and prepares its
/// run, checked against the plan's fingerprint.
fn open_run(
    dir: &Path,
    plan: &PlanFile,
) -> Result<(crate::bundle::Bundle, crate::tiles::TiledRun, String), ExitCode> {
    let paths: Vec<PathBuf> = plan.bundles.iter().map(|p| dir.join(p)).collect();
    let mut b = open_bundles(&paths)?;
    let run = start(&mut b, &plan.settings, true)?;
    if let Err(e) = plan.check(&run) {
        eprintln!("{}: {e}", dir.join("plan.json").display());
        return Err(ExitCode::from(EXIT_INVALID_INPUT));
    }
    Ok((b, run, plan.bundles.join(" + ")))
}

/// Whether `bytes` is a sound checkpoint of tile `index` of the plan (every entry
/// inflates with its CRC, the header names the plan's run and the tile).
fn check_checkpoint(bytes: &[u8], plan: &PlanFile, index: usize) -> Result<(), String> {
    let (f, fp) = checkpoint::decode(bytes)?;
    let fp = format!("{fp:016x}");
    if fp != plan.fingerprint {
        return Err(format!(
            "made by another run (fingerprint {fp}, the plan's is {})",
            plan.fingerprint
        ));
    }
    if f.index != index {
        return Err(format!("it is tile {} of its plan, not {index}", f.index));
    }
    Ok(())
}

/// `rogs reconstruct --plan PLAN --tile NAME --out DIR`: one tile job.
pub fn run_tile(dir: &Path, tile: &str, out: &Path) -> Result<ExitCode, String> {
    let plan = match read_plan(dir) {
        Ok(p) => p,
        Err(e) => return bad(e),
    };
    let index = match plan.index_of(tile) {
        Ok(k) => k,
        Err(e) => return bad(format!("{}: {e}", dir.join("plan.json").display())),
    };
    let file = out.join(format!("{tile}{}", checkpoint::SUFFIX));
    if let Ok(bytes) = std::fs::read(&file) {
        match check_checkpoint(&bytes, &plan, index) {
            Ok(()) => {
                eprintln!(
                    "tile {tile} is already finished ({}); delete it to train the tile again",
                    file.display()
                );
                return Ok(ExitCode::SUCCESS);
            }
            Err(e) => eprintln!("{}: {e}: training tile {tile} again", file.display()),
        }
    }
    let t0 = std::time::Instant::now();
    let (b, mut run, _) = match open_run(dir, &plan) {
        Ok(v) => v,
        Err(code) => return Ok(code),
    };
    if let Err(e) = run.only(index) {
        return bad(e.to_string());
    }
    run.checkpoints = true;
    let name = run.tiles[index].name();
    eprintln!(
        "tile {name} ({}/{} of the plan): {} views, {} steps",
        index + 1,
        plan.jobs.len(),
        run.tiles[index].views.len(),
        run.total_steps()
    );
    std::fs::create_dir_all(out).map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    let stopped = train(&mut run, &b, out)?;
    if stopped || !file.is_file() {
        eprintln!("tile {name} did not finish: run the job again");
        return Ok(ExitCode::from(EXIT_MACHINE));
    }
    let bytes = std::fs::read(&file).map_err(|e| format!("{}: {e}", file.display()))?;
    let job = serde_json::json!({
        "tile": name,
        "index": index,
        "fingerprint": plan.fingerprint,
        "checkpoint": file.file_name().map(|n| n.to_string_lossy().to_string()),
        "checkpoint_bytes": bytes.len(),
        "seconds": t0.elapsed().as_secs_f64(),
        "peak_gpu_bytes": run.peak_gpu_bytes,
        "peak_host_bytes": crate::mem::peak_host_bytes(),
        "report": run.reports.last(),
    });
    let p = out.join("job.json");
    let json = serde_json::to_vec_pretty(&job).map_err(|e| e.to_string())?;
    std::fs::write(&p, json).map_err(|e| format!("cannot write {}: {e}", p.display()))?;
    eprintln!("tile {name} finished: {}", file.display());
    Ok(ExitCode::SUCCESS)
}

/// `rogs merge PLAN TILES --out MAP`.
pub fn merge(a: MergeArgs) -> Result<ExitCode, String> {
    let plan = match read_plan(&a.plan) {
        Ok(p) => p,
        Err(e) => return bad(e),
    };
    // Every tile's output first: a missing one is named before any work.
    let missing: Vec<&str> = plan
        .jobs
        .iter()
        .filter(|j| !checkpoint_path(&a.tiles, &j.tile).is_file())
        .map(|j| j.tile.as_str())
        .collect();
    if !missing.is_empty() {
        return bad(format!(
            "{} of {} tiles have no checkpoint in {}: {}{}; run them first \
             (rogs reconstruct --plan {} --tile NAME --out {}/NAME)",
            missing.len(),
            plan.jobs.len(),
            a.tiles.display(),
            missing
                .iter()
                .take(12)
                .copied()
                .collect::<Vec<_>>()
                .join(", "),
            if missing.len() > 12 { ", …" } else { "" },
            a.plan.display(),
            a.tiles.display()
        ));
    }
    let (b, mut run, name) = match open_run(&a.plan, &plan) {
        Ok(v) => v,
        Err(code) => return Ok(code),
    };
    // The tiles' surfels stay in their checkpoints until the model is written.
    run.spill_models(a.tiles.clone());
    // In the plan's order: the order the single-process run adds its tiles in.
    for j in &plan.jobs {
        let p = checkpoint_path(&a.tiles, &j.tile);
        let bytes = std::fs::read(&p).map_err(|e| format!("cannot read {}: {e}", p.display()))?;
        if let Err(e) = run.restore_file(&bytes, Some(&p)) {
            return bad(format!(
                "{}: {e} (delete it and run its job again)",
                p.display()
            ));
        }
    }
    eprintln!(
        "{} tiles restored from {}",
        run.tiles_done(),
        a.tiles.display()
    );
    std::fs::create_dir_all(&a.out)
        .map_err(|e| format!("cannot create {}: {e}", a.out.display()))?;
    write_map(&a.out, &mut run, &b, &name, a.ply_up)?;
    Ok(ExitCode::SUCCESS)
}
