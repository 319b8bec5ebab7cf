//! Typed bundle problems. Each names the file or manifest field it concerns and says
//! what was expected, so that a person can fix the bundle without reading our code.

use thiserror::Error;

#[derive(Clone, Debug, PartialEq, Error)]
pub enum Problem {
    #[error("the bundle is not a readable zip archive ({0}); expected a .zip with manifest.json at its root")]
    NotZip(String),
    #[error("manifest.json is missing at the bundle root; expected a file named exactly manifest.json (not inside a sub-folder)")]
    MissingManifest,
    #[error("manifest.json is not valid JSON: {0}")]
    ManifestSyntax(String),
    #[error("{field}: {what}")]
    ManifestField { field: String, what: String },
    #[error("format: found {found:?}, expected \"rogs-bundle\"")]
    Format { found: String },
    #[error("version: found {found}, this build reads version {supported}")]
    Version { found: u32, supported: u32 },
    #[error("{field}: path {path:?} is not allowed: {}; paths must be relative '/'-separated paths inside the bundle", unsafe_rule(path))]
    UnsafePath { field: String, path: String },
    #[error("{field}: file {path:?} is not in the bundle")]
    MissingFile { field: String, path: String },
    #[error("{path}: uncompressed size {size} bytes exceeds the limit of {limit} bytes")]
    FileTooLarge { path: String, size: u64, limit: u64 },
    #[error("{path}: image of {width}×{height} exceeds the limit of {limit} pixels per side")]
    ImageTooLarge {
        path: String,
        width: u32,
        height: u32,
        limit: u32,
    },
    #[error("{path}: cannot read it ({reason})")]
    Unreadable { path: String, reason: String },
    #[error("{path}: not read yet (files of a bundle opened lazily are read as the work needs them; this one was not asked for)")]
    NotLoaded { path: String },
    #[error("{path}: cannot decode the image ({reason}); expected PNG or JPEG")]
    ImageDecode { path: String, reason: String },
    #[error("{path}: image is {found_w}×{found_h}, expected {expected_w}×{expected_h} (camera {camera:?})")]
    ImageSize {
        path: String,
        camera: String,
        expected_w: u32,
        expected_h: u32,
        found_w: u32,
        found_h: u32,
    },
    #[error("{path}: label image must be 8-bit single-channel (grey) PNG, found {found}")]
    LabelFormat { path: String, found: String },
    #[error("{path}: label value {value} at pixel ({x}, {y}) is not a class id in semantic_classes ({pixels} pixels have unknown ids)")]
    LabelOutOfRange {
        path: String,
        value: u8,
        x: u32,
        y: u32,
        pixels: u64,
    },
    #[error("{field}: {what}")]
    Invalid { field: String, what: String },
    #[error("{field}: contains a non-finite number (NaN or infinity); expected finite metres and unit rotation")]
    NonFinite { field: String },
    #[error("{field}: rotation part is not orthonormal with determinant +1 (max deviation {deviation:.2e}, tolerance {tolerance:.0e})")]
    NotRotation {
        field: String,
        deviation: f64,
        tolerance: f64,
    },
    #[error("{field}: last row must be [0, 0, 0, 1]")]
    NotRigid { field: String },
    #[error("frames: found {found} frame(s), expected at least 2")]
    TooFewFrames { found: usize },
    #[error("{path}: {len} bytes is not a multiple of the point size {stride} bytes ({floats} float32 per point)")]
    LidarStride {
        path: String,
        len: u64,
        stride: u64,
        floats: u32,
    },
    #[error("{path}: {len} bytes, expected {expected} (width × height float32 values)")]
    ElevationSize {
        path: String,
        len: u64,
        expected: u64,
    },
    #[error("zip entry {path:?} is not allowed: {rule}; entry names must be relative '/'-separated paths inside the bundle")]
    UnsafeEntry { path: String, rule: &'static str },
}

impl Problem {
    /// The file path or manifest field this problem is about (empty for the archive itself).
    pub fn location(&self) -> &str {
        use Problem::*;
        match self {
            NotZip(_) => "",
            MissingManifest | ManifestSyntax(_) => "manifest.json",
            Format { .. } => "format",
            Version { .. } => "version",
            TooFewFrames { .. } => "frames",
            UnsafePath { field, .. }
            | MissingFile { field, .. }
            | Invalid { field, .. }
            | ManifestField { field, .. }
            | NonFinite { field }
            | NotRotation { field, .. }
            | NotRigid { field } => field,
            FileTooLarge { path, .. }
            | ImageTooLarge { path, .. }
            | Unreadable { path, .. }
            | NotLoaded { path }
            | ImageDecode { path, .. }
            | ImageSize { path, .. }
            | LabelFormat { path, .. }
            | LabelOutOfRange { path, .. }
            | LidarStride { path, .. }
            | ElevationSize { path, .. }
            | UnsafeEntry { path, .. } => path,
        }
    }
}

/// All problems found in a bundle: validation never stops at the first.
#[derive(Clone, Debug, PartialEq, Error)]
#[error("{}", render(.0))]
pub struct BundleErrors(pub Vec<Problem>);

fn render(problems: &[Problem]) -> String {
    let mut s = format!("the bundle has {} problem(s):", problems.len());
    for p in problems {
        s.push_str("\n  - ");
        s.push_str(&p.to_string());
    }
    s
}

/// The rule an unsafe path breaks, in words.
pub fn unsafe_rule(path: &str) -> &'static str {
    if path.is_empty() {
        "it is empty"
    } else if path.starts_with('/') {
        "it is absolute (starts with '/')"
    } else if path.contains('\\') {
        "it contains '\\' (use '/')"
    } else if path.contains(':') {
        "it contains ':' (a drive letter or stream name)"
    } else if path.contains('\0') {
        "it contains a NUL byte"
    } else if path.split('/').any(|c| c == "..") {
        "it contains a '..' component"
    } else if path.split('/').any(|c| c == ".") {
        "it contains a '.' component"
    } else {
        "it contains an empty component ('//')"
    }
}
