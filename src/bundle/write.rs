//! Writes bundles as zip archives: in memory (so the page can export one too), or
//! streamed file by file, manifest last, so that an importer never holds a whole
//! dataset in memory. Our reader goes by the zip's central directory, so the
//! manifest's position in the archive does not matter.

use super::manifest::Manifest;
use super::MANIFEST;
use std::io::{Cursor, Seek, Write};
use zip::write::SimpleFileOptions;
use zip::CompressionMethod;

/// One file of a bundle: its path inside the archive and its bytes.
pub type BundleFile = (String, Vec<u8>);

/// Zips the manifest and files. PNG/JPEG are stored (already compressed); the rest is
/// deflated.
pub fn write_zip(manifest: &Manifest, files: &[BundleFile]) -> Result<Vec<u8>, String> {
    let json = serde_json::to_vec_pretty(manifest).map_err(|e| e.to_string())?;
    let mut zip = ZipBundleWriter::new(Cursor::new(Vec::new()));
    zip.add(MANIFEST, &json)?;
    for (name, bytes) in files {
        zip.add(name, bytes)?;
    }
    Ok(zip.finish_raw()?.into_inner())
}

/// A bundle written into a zip one file at a time; `finish` adds the manifest.
pub struct ZipBundleWriter<W: Write + Seek> {
    zip: zip::ZipWriter<W>,
}

impl<W: Write + Seek> ZipBundleWriter<W> {
    pub fn new(out: W) -> Self {
        Self {
            zip: zip::ZipWriter::new(out),
        }
    }

    /// Adds one file. Compressed images are stored as they are: deflating them again
    /// costs time and gains nothing.
    pub fn add(&mut self, name: &str, bytes: &[u8]) -> Result<(), String> {
        let compressed = [".png", ".jpg", ".jpeg"].iter().any(|e| name.ends_with(e));
        let method = if compressed {
            CompressionMethod::Stored
        } else {
            CompressionMethod::Deflated
        };
        self.zip
            .start_file(
                name,
                SimpleFileOptions::default().compression_method(method),
            )
            .map_err(|e| format!("{name}: {e}"))?;
        self.zip
            .write_all(bytes)
            .map_err(|e| format!("{name}: {e}"))
    }

    /// Writes the manifest and the central directory; returns the sink.
    pub fn finish(mut self, manifest: &Manifest) -> Result<W, String> {
        let json = serde_json::to_vec_pretty(manifest).map_err(|e| e.to_string())?;
        self.add(MANIFEST, &json)?;
        self.finish_raw()
    }

    /// Writes the central directory only (archives that are not bundles).
    pub fn finish_raw(self) -> Result<W, String> {
        self.zip.finish().map_err(|e| e.to_string())
    }
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
