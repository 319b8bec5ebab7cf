//! `rogs segment`: labels every view of a bundle with a road-segmentation network.

use super::progress::Progress;
use super::EXIT_INVALID_INPUT;
use crate::bundle::{Bundle, Limits};
use crate::segment::{label_bundle, ClassMap, Segmenter};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// The bundle to label (.zip or folder); usually a drive without masks.
    bundle: PathBuf,
    /// The segmentation network, an ONNX file (e.g. shared/models/twinlitenet).
    #[arg(long)]
    model: PathBuf,
    /// How the model's outputs become classes: `twinlitenet` (the built-in map of
    /// that network: 0 other, 1 road, 2 lane marking) or a JSON class map
    /// (docs/SEGMENT.md).
    #[arg(long)]
    classes: String,
    /// The labelled bundle to write (.zip).
    #[arg(long)]
    out: PathBuf,
}

fn refuse(what: impl std::fmt::Display) -> Result<ExitCode, String> {
    eprintln!("error: {what}");
    Ok(ExitCode::from(EXIT_INVALID_INPUT))
}

pub fn run(a: Args) -> Result<ExitCode, String> {
    let map = if a.classes == "twinlitenet" {
        ClassMap::twinlitenet()
    } else {
        let text = match std::fs::read(&a.classes) {
            Ok(t) => t,
            Err(e) => {
                return refuse(format!(
                    "{}: cannot read the class map ({e}); give `twinlitenet` or a JSON \
                     class map (docs/SEGMENT.md)",
                    a.classes
                ))
            }
        };
        match ClassMap::from_json(&a.classes, &text) {
            Ok(m) => m,
            Err(e) => return refuse(e),
        }
    };
    let model_name = a.model.display().to_string();
    let bytes = match std::fs::read(&a.model) {
        Ok(b) => b,
        Err(e) => return refuse(format!("{model_name}: cannot read the model ({e})")),
    };
    let seg = match Segmenter::new(&model_name, &bytes, map) {
        Ok(s) => s,
        Err(e) => return refuse(e),
    };
    let mut progress = Progress::new("checking");
    let opened = Bundle::open(&a.bundle, Limits::default(), &mut |d, t| {
        progress.update(d, t)
    });
    progress.finish();
    let b = match opened {
        Ok(b) => b,
        Err(errors) => {
            eprintln!("{}: invalid bundle: {errors}", a.bundle.display());
            return Ok(ExitCode::from(EXIT_INVALID_INPUT));
        }
    };
    // Written beside the output and moved into place once it validates.
    let partial = a.out.with_extension("zip.partial");
    let file =
        std::fs::File::create(&partial).map_err(|e| format!("{}: {e}", partial.display()))?;
    let t0 = std::time::Instant::now();
    let mut progress = Progress::new("segmenting");
    let done = label_bundle(&b, &seg, std::io::BufWriter::new(file), &mut |d, t| {
        progress.update(d, t)
    });
    progress.finish();
    let done = match done {
        Ok(d) => d,
        Err(e) => {
            let _ = std::fs::remove_file(&partial);
            return Err(e);
        }
    };
    drop(done.sink);
    for n in &done.notes {
        eprintln!("note: {n}");
    }
    if let Err(errors) = Bundle::open(&partial, Limits::default(), &mut |_, _| {}) {
        return Err(format!(
            "the labelled bundle is invalid (kept at {}): {errors}",
            partial.display()
        ));
    }
    std::fs::rename(&partial, &a.out).map_err(|e| format!("{}: {e}", a.out.display()))?;
    let views: usize = done.manifest.frames.iter().map(|f| f.views.len()).sum();
    let secs = t0.elapsed().as_secs_f64();
    println!(
        "wrote {} ({views} views labelled in {secs:.1} s, {:.0} ms per view)",
        a.out.display(),
        1e3 * secs / views.max(1) as f64
    );
    Ok(ExitCode::SUCCESS)
}
