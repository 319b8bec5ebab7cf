//! The native command line: `rogs <command>`. Each command lives in its own file.

mod bench;
mod bench_step;
mod eval;
mod example;
mod gpu;
mod import;
mod inspect;
mod jobs;
pub mod progress;
mod reconstruct;
mod segment;
mod synth;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// Exit code for input the user must fix (an invalid bundle or map, a map too large
/// for the settings). 2 is the argument parser's (a misspelled flag or value).
pub const EXIT_INVALID_INPUT: u8 = 3;
/// Exit code when the machine could not do it (no GPU adapter, a device lost, a
/// file that cannot be written, a run stopped part-way: what was finished is kept).
pub const EXIT_MACHINE: u8 = 4;

#[derive(Parser)]
#[command(
    name = "rogs",
    version,
    about = "Road-surface mapping with 2D Gaussian surfels",
    long_about = "rogs builds bird's-eye-view road maps (RGB, semantics, elevation) from a scene \
bundle: camera images, semantic masks, poses, intrinsics and optional LiDAR.\n\n\
A scene bundle is a .zip (or folder) with manifest.json at its root; docs/BUNDLE.md \
describes the format. GPU work runs through wgpu: set WGPU_BACKEND=vulkan to pick Vulkan \
(Mesa's lavapipe works without a GPU)."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Validate a scene bundle and print its summary, or every problem found.
    ///
    /// Prints cameras, frames, trajectory length, classes, LiDAR points and whether
    /// ground truth is present. Exits with code 3 when the bundle is invalid, listing
    /// each problem with the file or manifest field it concerns.
    Inspect(inspect::Args),
    /// Report the GPU adapter and run a compute self-test against the CPU.
    ///
    /// Shows the adapter name, backend, limits and the gradient-accumulation strategy
    /// chosen from its features, then checks a scatter-add kernel on the GPU against
    /// the CPU. Fails with advice on what to install when no adapter is found.
    Gpu(gpu::Args),
    /// Write the tiny example bundle (format reference and test fixture).
    ///
    /// The example has every optional part (LiDAR, ground truth) with tiny images; it
    /// shows the format, it is not a road scene.
    Example(example::Args),
    /// Generate a synthetic road scene bundle with exact ground truth.
    ///
    /// A procedural road (lanes, dashed and solid markings, crosswalk, stop line,
    /// curbs with a height step, sidewalks, slope and cross-fall, a speed table,
    /// cracks and patches, a manhole, parked cars) is rendered by an independent CPU
    /// ray caster from the true poses; the bundle gets the poses with the requested
    /// noise, and BEV truth rasters (RGB, classes, elevation, validity).
    Synth(synth::Args),
    /// Score a predicted BEV map: PSNR, mIoU, elevation RMSE / MAE / 95th percentile.
    ///
    /// The reference is the bundle's BEV truth, or the LiDAR pseudo-ground-truth when
    /// it has none (elevation then against the nearest LiDAR point within 0.1 m in
    /// xy). Prints {"metrics": {...}} as JSON.
    Eval(eval::Args),
    /// Benchmarks: measured speed and memory, median of several runs.
    #[command(subcommand)]
    Bench(bench::Bench),
    /// Convert a public dataset (KITTI odometry, nuScenes) into a scene bundle.
    ///
    /// Images are streamed into the zip one at a time; the result is validated like
    /// `rogs inspect` does before it is moved into place (exit code 3 and every
    /// problem listed when it is invalid). docs/IMPORT.md describes the layouts and
    /// every transform.
    Import(import::Args),
    /// Reconstruct the road surface: BEV map layers, surfel PLY and a report.
    ///
    /// Prepares the surfel grid along the trajectory, colours it from the best
    /// training views (the IPM baseline), optimises it on the GPU for the requested
    /// epochs, renders the BEV layers and scores them against the bundle's truth or
    /// LiDAR when present. Writes to --out (docs/OUTPUTS.md): rgb.png, semantic.png,
    /// semantic_ids.png, elevation.png and elevation_legend.png, elevation.npy /
    /// elevation.f32 with bev.json (georeference), GeoTIFFs elevation.tif, rgb.tif and
    /// semantic.tif, confidence.png, density.png, error.png (with truth),
    /// map.rogsmap (the map file for review), surfels.ply, surfels_semantic.ply and
    /// surfel_centres.f32 (these three as soon as training ends, before the BEV) and
    /// report.json. A NaN during optimisation stops it, keeps the
    /// last good model, still writes the outputs and exits non-zero.
    Reconstruct(reconstruct::Args),
    /// Write a reconstruction's tiles as independent jobs, for a scheduler.
    ///
    /// Takes the bundles and settings of `rogs reconstruct` and writes PLAN/plan.json
    /// (bundles, settings, the run's fingerprint, the tiles in merge order) and
    /// PLAN/jobs/NAME.json per tile (its square, views, steps, seed and the command
    /// that runs it). Each job runs with `rogs reconstruct --plan PLAN --tile NAME
    /// --out TILES/NAME`, anywhere that sees the bundles; `rogs merge` then makes the
    /// map. Tiles are 96 m unless --tile-m says otherwise. docs/DISTRIBUTED.md.
    Plan(jobs::PlanArgs),
    /// Stitch the tile jobs of a plan into the map `rogs reconstruct` would write.
    ///
    /// Reads TILES/NAME/NAME.tile for every tile of the plan (a missing or damaged one
    /// is named, exit code 3), adds them in the plan's order and writes the same
    /// outputs as `rogs reconstruct`: the layers, GeoTIFFs, PLY, map.rogsmap and
    /// report.json. The map equals the single-process tiled run's.
    Merge(jobs::MergeArgs),
    /// Label every view of a bundle with a road-segmentation network (ONNX).
    ///
    /// Runs the model on each image (resized to the model's input, in batches, so
    /// memory stays flat), maps its outputs to classes with --classes and writes the
    /// bundle with a label per view and the class map's class table: the bundle a
    /// labelled drive would be. docs/SEGMENT.md.
    Segment(segment::Args),
}

pub fn run() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Inspect(a) => inspect::run(a),
        Command::Gpu(a) => gpu::run(a),
        Command::Example(a) => example::run(a),
        Command::Synth(a) => synth::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Bench(b) => bench::run(b),
        Command::Import(a) => import::run(a),
        Command::Reconstruct(a) => match reconstruct::tile_job(&a) {
            Some((plan, tile, out)) => jobs::run_tile(plan, tile, out),
            None => reconstruct::run(a),
        },
        Command::Plan(a) => jobs::plan(a),
        Command::Merge(a) => jobs::merge(a),
        Command::Segment(a) => segment::run(a),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(EXIT_MACHINE)
        }
    }
}
