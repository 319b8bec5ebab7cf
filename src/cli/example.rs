//! `rogs example --out FILE.zip|DIR`: writes the tiny example bundle;
//! `rogs example --malformed --out DIR`: the catalogue of malformed bundles.

use crate::bundle::{catalogue, example, write_dir, write_zip};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// Output: a path ending in .zip writes an archive, anything else a folder.
    #[arg(long)]
    out: PathBuf,
    /// Write the catalogue of malformed bundles into the --out folder instead: one zip
    /// per case, each breaking one thing of the example, and catalogue.json saying for
    /// each what it breaks and what its refusal must name (docs/RELIABILITY.md).
    #[arg(long)]
    malformed: bool,
}

pub fn run(a: Args) -> Result<ExitCode, String> {
    if a.malformed {
        let n = catalogue::write(&a.out)?;
        eprintln!(
            "wrote {n} malformed bundles and catalogue.json into {}",
            a.out.display()
        );
        return Ok(ExitCode::SUCCESS);
    }
    let (manifest, files) = example::tiny();
    if a.out.extension().is_some_and(|e| e == "zip") {
        let bytes = write_zip(&manifest, &files)?;
        std::fs::write(&a.out, bytes).map_err(|e| format!("{}: {e}", a.out.display()))?;
    } else {
        write_dir(&a.out, &manifest, &files).map_err(|e| format!("{}: {e}", a.out.display()))?;
    }
    eprintln!("wrote {}", a.out.display());
    Ok(ExitCode::SUCCESS)
}
