//! `rogs inspect BUNDLE|MAP.rogsmap`: validate and summarise a scene bundle or a map
//! file (docs/MAP.md).

use super::progress::Progress;
use super::EXIT_INVALID_INPUT;
use crate::bundle::{Bundle, Limits};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// The bundle (a .zip file or a folder with manifest.json at its root), or a map
    /// file (.rogsmap, written by `rogs reconstruct`).
    bundle: PathBuf,
    /// Print the summary (or the problems) as JSON instead of text.
    #[arg(long)]
    json: bool,
    /// Refuse files whose uncompressed size exceeds this many MiB (zip-bomb guard).
    #[arg(long, default_value_t = 256)]
    max_file_mib: u64,
    /// Refuse images wider or taller than this many pixels.
    #[arg(long, default_value_t = 8192)]
    max_image_side: u32,
}

pub fn run(a: Args) -> Result<ExitCode, String> {
    let limits = Limits {
        max_file_bytes: a.max_file_mib << 20,
        max_image_side: a.max_image_side,
        // Every image decoded: a truncated or corrupt one is named here, not mid-run.
        decode_images: true,
        ..Limits::default()
    };
    if a.bundle.extension().is_some_and(|e| e == "rogsmap") {
        return inspect_map(&a, limits);
    }
    let mut progress = Progress::new("checking");
    let opened = Bundle::open(&a.bundle, limits, &mut |d, t| progress.update(d, t));
    progress.finish();
    match opened {
        Ok(b) => {
            let s = b.summary();
            if a.json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&s).map_err(|e| e.to_string())?
                );
            } else {
                print!("{}", s.to_text());
            }
            Ok(ExitCode::SUCCESS)
        }
        Err(errors) => {
            if a.json {
                print_problems(&errors);
            }
            eprintln!("{}: invalid bundle: {errors}", a.bundle.display());
            eprintln!("See docs/BUNDLE.md for the expected format.");
            Ok(ExitCode::from(EXIT_INVALID_INPUT))
        }
    }
}

/// Validates a map file: every tile of every level.
fn inspect_map(a: &Args, limits: Limits) -> Result<ExitCode, String> {
    let bytes =
        std::fs::read(&a.bundle).map_err(|e| format!("cannot read {}: {e}", a.bundle.display()))?;
    match crate::export::map_file::validate(bytes, &limits) {
        Ok(s) => {
            if a.json {
                let j = serde_json::json!({
                    "format": s.index.format, "version": s.index.version, "name": s.index.name,
                    "origin": s.index.origin, "resolution_m": s.index.resolution,
                    "width": s.index.width, "height": s.index.height, "levels": s.index.levels,
                    "layers": s.index.layers, "values": s.index.values,
                    "classes": s.index.classes.len(), "frames": s.index.trajectory.len(),
                    "tiles": s.tiles, "bytes": s.bytes,
                });
                println!(
                    "{}",
                    serde_json::to_string_pretty(&j).map_err(|e| e.to_string())?
                );
            } else {
                let i = &s.index;
                println!(
                    "map {:?}: {}×{} px at {} m ({:.0} × {:.0} m), origin ({:.2}, {:.2})",
                    i.name,
                    i.width,
                    i.height,
                    i.resolution,
                    i.width as f64 * i.resolution,
                    i.height as f64 * i.resolution,
                    i.origin[0],
                    i.origin[1]
                );
                println!("layers: {} (+ values: {}), {} levels, {} tiles, {} classes, {} frames, {:.1} MiB",
                    i.layers.join(", "), i.values.join(", "), i.levels, s.tiles,
                    i.classes.len(), i.trajectory.len(), s.bytes as f64 / (1 << 20) as f64);
            }
            Ok(ExitCode::SUCCESS)
        }
        Err(errors) => {
            if a.json {
                print_problems(&errors);
            }
            eprintln!("{}: invalid map file: {errors}", a.bundle.display());
            eprintln!("See docs/MAP.md for the expected format.");
            Ok(ExitCode::from(EXIT_INVALID_INPUT))
        }
    }
}

/// The problems as JSON on stdout (`--json`).
fn print_problems(errors: &crate::bundle::BundleErrors) {
    let list: Vec<_> = errors
        .0
        .iter()
        .map(|p| serde_json::json!({"location": p.location(), "message": p.to_string()}))
        .collect();
    println!("{}", serde_json::json!({ "problems": list }));
}
