//! `rogs inspect BUNDLE`: validate and summarise.

use super::progress::Progress;
use super::EXIT_INVALID_INPUT;
use crate::bundle::{Bundle, Limits};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// The bundle: a .zip file or a folder with manifest.json at its root.
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
        ..Limits::default()
    };
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
                let list: Vec<_> = errors
                    .0
                    .iter()
                    .map(
                        |p| serde_json::json!({"location": p.location(), "message": p.to_string()}),
                    )
                    .collect();
                println!("{}", serde_json::json!({ "problems": list }));
            }
            eprintln!("{}: invalid bundle: {errors}", a.bundle.display());
            eprintln!("See docs/BUNDLE.md for the expected format.");
            Ok(ExitCode::from(EXIT_INVALID_INPUT))
        }
    }
}
