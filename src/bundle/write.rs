//! Writes bundles as zip archives (in memory, so the page can export one too).

use super::manifest::Manifest;
use super::MANIFEST;
use std::io::{Cursor, Write};
use zip::write::SimpleFileOptions;
use zip::CompressionMethod;

/// One file of a bundle: its path inside the archive and its bytes.
pub type BundleFile = (String, Vec<u8>);

/// Zips the manifest and files. PNG/JPEG are stored (already compressed); the rest is
/// deflated.
pub fn write_zip(manifest: &Manifest, files: &[BundleFile]) -> Result<Vec<u8>, String> {
    let mut zip = zip::ZipWriter::new(Cursor::new(Vec::new()));
    let deflate = SimpleFileOptions::default().compression_method(CompressionMethod::Deflated);
    let stored = SimpleFileOptions::default().compression_method(CompressionMethod::Stored);
    let json = serde_json::to_vec_pretty(manifest).map_err(|e| e.to_string())?;
    let mut put = |name: &str, bytes: &[u8]| -> Result<(), String> {
        let compressed = [".png", ".jpg", ".jpeg"].iter().any(|e| name.ends_with(e));
        zip.start_file(name, if compressed { stored } else { deflate })
            .map_err(|e| format!("{name}: {e}"))?;
        zip.write_all(bytes).map_err(|e| format!("{name}: {e}"))
    };
    put(MANIFEST, &json)?;
    for (name, bytes) in files {
        put(name, bytes)?;
    }
    let out = zip.finish().map_err(|e| e.to_string())?;
    Ok(out.into_inner())
}

/// Writes the bundle as a folder (native only).
#[cfg(not(target_arch = "wasm32"))]
pub fn write_dir(
    dir: &std::path::Path,
    manifest: &Manifest,
    files: &[BundleFile],
) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let json = serde_json::to_vec_pretty(manifest)?;
    std::fs::write(dir.join(MANIFEST), json)?;
    for (name, bytes) in files {
        let p = dir.join(name);
        if let Some(parent) = p.parent() {
            std::fs::create_dir_all(parent)?;
        }
        std::fs::write(p, bytes)?;
    }
    Ok(())
}
