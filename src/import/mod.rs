//! Dataset importers: public dataset layouts (KITTI odometry, nuScenes) turned into
//! scene bundles (docs/IMPORT.md).
//!
//! Both importers stream: each image is read, checked (labels remapped and encoded)
//! and written into the zip before the next is touched, so memory stays flat however
//! long the sequence. The written file is then opened with the bundle validator, the
//! same one `rogs inspect` runs; only a bundle that passes is renamed into place.

pub mod kitti;
pub mod nuscenes;

use crate::bundle::{
    decode_label, image_dims, Bundle, BundleErrors, ClassRole, Limits, Manifest, Mat4Rows,
    SemanticClass, ZipBundleWriter,
};
use std::collections::HashSet;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// Why an import did not produce a bundle.
#[derive(Debug)]
pub enum ImportError {
    /// The input is missing or malformed; the message says what and how to fix it.
    Input(String),
    /// The written bundle failed validation (kept at `partial` for inspection).
    Invalid {
        problems: BundleErrors,
        partial: PathBuf,
    },
}

impl std::fmt::Display for ImportError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ImportError::Input(s) => f.write_str(s),
            ImportError::Invalid { problems, partial } => write!(
                f,
                "the imported bundle is invalid (kept as {}): {problems}",
                partial.display()
            ),
        }
    }
}

impl From<String> for ImportError {
    fn from(s: String) -> Self {
        ImportError::Input(s)
    }
}

/// A validated bundle on disk.
#[derive(Debug)]
pub struct Imported {
    pub manifest: Manifest,
    pub path: PathBuf,
    pub bytes: u64,
    /// Things the user should know (approximations, missing labels).
    pub warnings: Vec<String>,
}

/// `(stage, done, total)`, called as frames are written and then validated.
pub type ProgressFn<'a> = &'a mut dyn FnMut(&str, usize, usize);

pub(crate) fn class(id: u8, name: &str, color: [u8; 3], role: ClassRole) -> SemanticClass {
    SemanticClass {
        id,
        name: name.into(),
        color,
        role,
    }
}

pub(crate) const NO_LABELS_WARNING: &str = "no labels given: a drive without masks. The road \
plane below each camera's horizon is supervised, cars and people on it are down-weighted by \
the robust loss, and the map has no semantic layer (docs/BUNDLE.md). Give segmentation masks \
with --labels for a semantic layer.";

/// Reads a class table: a JSON array of bundle `SemanticClass` objects.
pub fn read_classes(path: &Path) -> Result<Vec<SemanticClass>, String> {
    let text = std::fs::read(path).map_err(|e| {
        format!(
            "{}: cannot read the class table ({e}); expected a JSON array like \
             [{{\"id\": 1, \"name\": \"road\", \"color\": [128, 64, 128], \"role\": \"road\"}}]",
            path.display()
        )
    })?;
    parse_classes(&text, path)
}

/// A class table from its bytes (`path` names it in errors).
pub fn parse_classes(text: &[u8], path: &Path) -> Result<Vec<SemanticClass>, String> {
    let classes: Vec<SemanticClass> = serde_json::from_slice(text).map_err(|e| {
        format!(
            "{}: not a class table ({e}); expected a JSON array of objects with \"id\" \
             (0-255), \"name\", \"color\" [r, g, b] and \"role\" (\"road\" or \"ignore\")",
            path.display()
        )
    })?;
    if !classes.iter().any(|c| c.role == ClassRole::Road) {
        return Err(format!(
            "{}: no class has role \"road\"; nothing would be reconstructed",
            path.display()
        ));
    }
    Ok(classes)
}

/// A path given on the command line: as given when it exists, else under the dataset
/// root (so `--labels sequences/00/semantic` works from anywhere).
pub(crate) fn resolve(root: &Path, p: &Path) -> PathBuf {
    if p.is_relative() && !p.exists() && root.join(p).exists() {
        root.join(p)
    } else {
        p.to_path_buf()
    }
}

pub(crate) fn read_file(path: &Path, what: &str) -> Result<Vec<u8>, String> {
    std::fs::read(path).map_err(|e| format!("{}: cannot read {what} ({e})", path.display()))
}

/// Width and height from an image header, with an error naming the file.
pub(crate) fn header_dims(path: &Path, bytes: &[u8]) -> Result<(u32, u32), String> {
    image_dims(&path.display().to_string(), bytes, &Limits::default()).map_err(|p| p.to_string())
}

/// Checks a label PNG (8-bit grey, the image's size, known ids) so that a bad mask is
/// reported with its source path rather than as a bundle problem later.
pub(crate) fn check_label(
    path: &Path,
    bytes: &[u8],
    size: (u32, u32),
    known: &[bool; 256],
) -> Result<(), String> {
    let name = path.display().to_string();
    let img = decode_label(&name, bytes, &Limits::default()).map_err(|p| {
        format!("{p}; labels must be 8-bit single-channel PNGs of class ids (not colour masks)")
    })?;
    if img.dimensions() != size {
        return Err(format!(
            "{name}: label is {}×{}, its image is {}×{}; labels must match their image",
            img.width(),
            img.height(),
            size.0,
            size.1
        ));
    }
    if let Some(p) = img.pixels().find(|p| !known[p.0[0] as usize]) {
        return Err(format!(
            "{name}: label value {} is not in the class table; add it to --classes",
            p.0[0]
        ));
    }
    Ok(())
}

pub(crate) fn known_ids(classes: &[SemanticClass]) -> [bool; 256] {
    let mut known = [false; 256];
    for c in classes {
        known[c.id as usize] = true;
    }
    known
}

/// The bundle being written: a `.partial` file beside the output, renamed into place
/// once the validator accepts it. Dropped before `finish` (an input error midway), it
/// removes the partial file; an invalid result is kept for inspection.
pub(crate) struct Output {
    zip: Option<ZipBundleWriter<BufWriter<File>>>,
    partial: PathBuf,
    out: PathBuf,
    written: HashSet<String>,
    keep: bool,
}

impl Output {
    pub fn create(out: &Path) -> Result<Self, String> {
        let mut name = out.as_os_str().to_owned();
        name.push(".partial");
        let partial = PathBuf::from(name);
        let file = File::create(&partial)
            .map_err(|e| format!("{}: cannot create the output ({e})", partial.display()))?;
        Ok(Self {
            zip: Some(ZipBundleWriter::new(BufWriter::new(file))),
            partial,
            out: out.to_path_buf(),
            written: HashSet::new(),
            keep: false,
        })
    }

    /// Adds a file once; later calls with the same name are no-ops (shared labels).
    pub fn add(&mut self, name: &str, bytes: &[u8]) -> Result<(), String> {
        let zip = self.zip.as_mut().ok_or("the bundle is already finished")?;
        if self.written.insert(name.to_string()) {
            zip.add(name, bytes)
                .map_err(|e| format!("{}: {e}", self.partial.display()))?;
        }
        Ok(())
    }

    /// Writes the manifest, validates the whole file and moves it into place.
    pub fn finish(
        mut self,
        manifest: Manifest,
        warnings: Vec<String>,
        progress: ProgressFn,
    ) -> Result<Imported, ImportError> {
        let partial = self.partial.clone();
        let io = |e: String| ImportError::Input(format!("{}: {e}", partial.display()));
        let zip = self.zip.take().ok_or_else(|| io("finished twice".into()))?;
        let mut w = zip.finish(&manifest).map_err(io)?;
        std::io::Write::flush(&mut w).map_err(|e| io(e.to_string()))?;
        drop(w);
        let checked = Bundle::open(&partial, Limits::default(), &mut |d, t| {
            progress("validating", d, t)
        });
        if let Err(problems) = checked {
            self.keep = true;
            return Err(ImportError::Invalid { problems, partial });
        }
        std::fs::rename(&partial, &self.out)
            .map_err(|e| io(format!("cannot move it to {} ({e})", self.out.display())))?;
        self.keep = true;
        let bytes = std::fs::metadata(&self.out).map(|m| m.len()).unwrap_or(0);
        Ok(Imported {
            manifest,
            path: self.out.clone(),
            bytes,
            warnings,
        })
    }
}

impl Drop for Output {
    fn drop(&mut self) {
        if !self.keep {
            self.zip.take();
            std::fs::remove_file(&self.partial).ok();
        }
    }
}

/// A rigid transform from a row-major 3×3 rotation and a translation.
pub(crate) fn rigid(r: [[f64; 3]; 3], t: [f64; 3]) -> Mat4Rows {
    crate::bundle::transform::mat(r, t)
}

pub(crate) use crate::synth::rig::{apply, inverse, mul};
