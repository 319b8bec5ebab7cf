//! Helpers shared by the native test suites (each suite uses some of them).
#![allow(dead_code)]

use std::io::Read;

/// Every entry of a zip, inflated, in the archive's order: what the page's reader
/// returns entry by entry.
pub fn zip_entries(zip: &[u8]) -> Vec<(String, Vec<u8>)> {
    let mut a = zip::ZipArchive::new(std::io::Cursor::new(zip)).expect("zip");
    (0..a.len())
        .map(|i| {
            let mut f = a.by_index(i).expect("entry");
            let mut v = Vec::new();
            f.read_to_end(&mut v).expect("read");
            (f.name().expect("name").to_string(), v)
        })
        .collect()
}

/// The standard output of `cmd args` run in `dir` (GDAL's tools, installed by
/// scripts/setup.sh); panics with its error output when it fails.
pub fn tool(dir: &std::path::Path, cmd: &str, args: &[&str]) -> Vec<u8> {
    let out = std::process::Command::new(cmd)
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap_or_else(|e| panic!("{cmd} (gdal-bin, installed by scripts/setup.sh): {e}"));
    assert!(
        out.status.success(),
        "{cmd} {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
}

/// A GeoTIFF's pixels as GDAL reads them (band-interleaved raw bytes, ENVI).
pub fn gdal_pixels(dir: &std::path::Path, tif: &str) -> Vec<u8> {
    let bin = format!("{tif}.bin");
    tool(dir, "gdal_translate", &["-q", "-of", "ENVI", tif, &bin]);
    std::fs::read(dir.join(&bin)).expect("gdal_translate output")
}
