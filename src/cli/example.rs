//! `rogs example --out FILE.zip|DIR`: writes the tiny example bundle.

use crate::bundle::{example, write_dir, write_zip};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// Output: a path ending in .zip writes an archive, anything else a folder.
    #[arg(long)]
    out: PathBuf,
}

pub fn run(a: Args) -> Result<ExitCode, String> {
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
