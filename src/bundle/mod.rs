//! Scene bundle v1: the input of every reconstruction (see docs/BUNDLE.md).
//!
//! `Bundle::from_zip_bytes` works everywhere (the page hands us the dropped file's
//! bytes); `Bundle::open` natively also takes a folder. Opening validates the whole
//! bundle, so later stages may rely on every file being present and well formed.

pub mod catalogue;
mod error;
pub mod example;
mod lazy;
mod manifest;
mod merge;
mod source;
mod summary;
pub mod surface;
pub mod transform;
mod unknown;
mod validate;
mod write;

pub use error::{BundleErrors, Problem};
pub use lazy::LazyFiles;
pub use manifest::*;
pub use merge::DRIVE_GAP_M;
pub use source::{is_safe_path, LazyStore, Limits, ReadSeek, Source, ZipSource};
pub use summary::Summary;
pub use validate::{
    check_rigid, decode_label, decode_rgb, image_dims, validate_views, ROTATION_TOLERANCE,
};
#[cfg(not(target_arch = "wasm32"))]
pub use write::write_dir;
pub use write::{write_zip, BundleFile, ZipBundleWriter};

#[cfg(not(target_arch = "wasm32"))]
pub use source::DirSource;

/// The name of the manifest at the bundle root.
pub const MANIFEST: &str = "manifest.json";

/// Parses manifest.json, naming the field of a type error (a string where a number
/// belongs, a missing key, `null` where a number was expected).
pub fn parse_manifest(text: &[u8]) -> Result<Manifest, Problem> {
    // serde reads a struct from a JSON list too (fields in order): name the real mistake.
    match text.iter().find(|b| !b.is_ascii_whitespace()) {
        Some(b'{') | None => {}
        Some(&b) => {
            let found = match b {
                b'[' => "a list",
                b'"' => "a string",
                b'n' => "null",
                b't' | b'f' => "a boolean",
                _ => "a number or something else",
            };
            return Err(Problem::ManifestField {
                field: MANIFEST.into(),
                what: format!(
                    "found {found} at the top level; expected an object {{ \"format\": \"rogs-bundle\", … }}"
                ),
            });
        }
    }
    let de = &mut serde_json::Deserializer::from_slice(text);
    serde_path_to_error::deserialize(de).map_err(|e| {
        let field = e.path().to_string();
        let inner = e.into_inner();
        if inner.is_syntax() || inner.is_eof() {
            Problem::ManifestSyntax(inner.to_string())
        } else if field == "." {
            // A required top-level field is missing: the manifest itself is named.
            Problem::ManifestField {
                field: MANIFEST.into(),
                what: format!("{inner}"),
            }
        } else {
            Problem::ManifestField {
                field,
                what: format!("{inner}"),
            }
        }
    })
}

/// A validated bundle: its manifest and the files it references.
pub struct Bundle {
    pub manifest: Manifest,
    pub limits: Limits,
    /// The drives whose frames the manifest holds, in order (one for a bundle as
    /// read; several after `Bundle::merge`).
    pub drives: Vec<Drive>,
    /// What the bundle holds that rogs ignores (unknown manifest fields, named with
    /// the nearest known one): shown by `rogs inspect` and the page.
    pub warnings: Vec<String>,
    source: Box<dyn Source>,
}

/// One drive of a (possibly merged) bundle: its name and its run of frames.
#[derive(Clone, Debug, PartialEq)]
pub struct Drive {
    pub name: String,
    pub frames: std::ops::Range<usize>,
}

impl Bundle {
    /// Reads and validates a bundle from the bytes of a `.zip`.
    pub fn from_zip_bytes(bytes: Vec<u8>, limits: Limits) -> Result<Self, BundleErrors> {
        Self::from_zip_bytes_with_progress(bytes, limits, &mut |_, _| {})
    }

    pub fn from_zip_bytes_with_progress(
        bytes: Vec<u8>,
        limits: Limits,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Self, BundleErrors> {
        let source = ZipSource::new(bytes, &limits).map_err(BundleErrors)?;
        Self::from_source(Box::new(source), limits, progress)
    }

    /// Reads and validates a bundle from a `.zip` file or a folder (native only).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn open(
        path: &std::path::Path,
        limits: Limits,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Self, BundleErrors> {
        if path.is_dir() {
            let source = DirSource { root: path.into() };
            return Self::from_source(Box::new(source), limits, progress);
        }
        // Read entry by entry from the file: a long drive is never held whole.
        let file = std::fs::File::open(path).map_err(|e| {
            BundleErrors(vec![Problem::Unreadable {
                path: path.display().to_string(),
                reason: e.to_string(),
            }])
        })?;
        let reader = Box::new(std::io::BufReader::new(file));
        let source = ZipSource::from_reader(reader, &limits).map_err(BundleErrors)?;
        Self::from_source(Box::new(source), limits, progress)
    }

    /// A bundle whose files are held only while needed (the page's lazy reading):
    /// `store` must hold manifest.json. Validation here is structural (manifest,
    /// presence, sizes); each view's image and label are checked by
    /// `validate_views` when they are provided, before any work uses them.
    pub fn from_store(
        store: std::sync::Arc<LazyStore>,
        limits: Limits,
    ) -> Result<Self, BundleErrors> {
        Self::open_with(Box::new(store), limits, &mut |m, s, l| {
            validate::validate_structure(m, s, l)
        })
    }

    /// Reads the manifest from `source`, checks the bundle with `check`.
    fn open_with(
        source: Box<dyn Source>,
        limits: Limits,
        check: &mut dyn FnMut(&Manifest, &dyn Source, &Limits) -> Vec<Problem>,
    ) -> Result<Self, BundleErrors> {
        if source.size(MANIFEST).is_none() {
            return Err(BundleErrors(vec![Problem::MissingManifest]));
        }
        let text = source
            .read(MANIFEST, &limits)
            .map_err(|p| BundleErrors(vec![p]))?;
        let manifest = parse_manifest(&text).map_err(|p| BundleErrors(vec![p]))?;
        let problems = check(&manifest, source.as_ref(), &limits);
        if !problems.is_empty() {
            return Err(BundleErrors(problems));
        }
        Ok(Self::checked(manifest, limits, source, &text))
    }

    fn checked(manifest: Manifest, limits: Limits, source: Box<dyn Source>, text: &[u8]) -> Self {
        let drives = vec![Drive {
            name: manifest.name.clone(),
            frames: 0..manifest.frames.len(),
        }];
        Self {
            warnings: unknown::unknown_fields(text, &manifest),
            manifest,
            limits,
            drives,
            source,
        }
    }

    /// Parses the manifest and validates every referenced file.
    pub fn from_source(
        source: Box<dyn Source>,
        limits: Limits,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Self, BundleErrors> {
        let mut advice = Vec::new();
        let mut b = Self::open_with(source, limits, &mut |m, s, l| {
            let (problems, a) = validate::validate(m, s, l, progress);
            advice = a;
            problems
        })?;
        b.warnings.extend(advice);
        Ok(b)
    }

    /// The files of view `view` of frame `frame`: its image, its label, and its
    /// camera's body mask when it has them.
    pub fn view_files(&self, frame: usize, view: usize) -> Vec<&str> {
        let v = &self.manifest.frames[frame].views[view];
        let mask = self
            .manifest
            .camera(&v.camera)
            .and_then(|c| c.mask.as_deref());
        [Some(v.image.as_str()), v.label.as_deref(), mask]
            .into_iter()
            .flatten()
            .collect()
    }

    /// The label of view `view` of frame `frame`: its label image, or in a drive
    /// without labels the road plane its camera sees (`surface::surface_label`).
    pub fn read_view_label(&self, frame: usize, view: usize) -> Result<image::GrayImage, Problem> {
        let v = &self.manifest.frames[frame].views[view];
        if let Some(l) = &v.label {
            return self.read_label(l);
        }
        let cam = self
            .manifest
            .camera(&v.camera)
            .ok_or_else(|| Problem::ManifestField {
                field: format!("frames[{frame}].views[{view}].camera"),
                what: format!("no camera named {:?}", v.camera),
            })?;
        let body = match &cam.mask {
            Some(p) => Some(decode_label(p, &self.read(p)?, &self.limits)?),
            None => None,
        };
        Ok(surface::surface_label(&self.manifest, cam, body.as_ref()))
    }

    /// Where the files come from.
    pub fn source(&self) -> &dyn Source {
        self.source.as_ref()
    }

    /// Raw bytes of a file in the bundle.
    pub fn read(&self, path: &str) -> Result<Vec<u8>, Problem> {
        self.source.read(path, &self.limits)
    }

    pub fn read_rgb(&self, path: &str) -> Result<image::RgbImage, Problem> {
        decode_rgb(path, &self.read(path)?, &self.limits)
    }

    pub fn read_label(&self, path: &str) -> Result<image::GrayImage, Problem> {
        decode_label(path, &self.read(path)?, &self.limits)
    }

    /// LiDAR points of a sweep, xyz in the LiDAR frame (intensity dropped).
    pub fn read_lidar(&self, path: &str) -> Result<Vec<[f32; 3]>, Problem> {
        let floats = self
            .manifest
            .lidar
            .as_ref()
            .map_or(3, |l| l.floats_per_point) as usize;
        let bytes = self.read(path)?;
        Ok(bytes
            .chunks_exact(4 * floats)
            .map(|p| {
                let f = |i: usize| {
                    f32::from_le_bytes([p[4 * i], p[4 * i + 1], p[4 * i + 2], p[4 * i + 3]])
                };
                [f(0), f(1), f(2)]
            })
            .collect())
    }

    /// The exact poses of `ground_truth.poses` (synthetic bundles), one per frame;
    /// `Ok(None)` when the bundle has none.
    pub fn read_true_poses(&self) -> Result<Option<Vec<Mat4Rows>>, Problem> {
        let Some(path) = self
            .manifest
            .ground_truth
            .as_ref()
            .and_then(|g| g.poses.as_deref())
        else {
            return Ok(None);
        };
        let field = "ground_truth.poses".to_string();
        let poses: Vec<Mat4Rows> =
            serde_json::from_slice(&self.read(path)?).map_err(|e| Problem::ManifestField {
                field: field.clone(),
                what: format!("{path}: {e}; expected an array of row-major 4×4 matrices"),
            })?;
        if poses.len() != self.manifest.frames.len() {
            return Err(Problem::ManifestField {
                field,
                what: format!(
                    "{path} holds {} poses, expected one per frame ({})",
                    poses.len(),
                    self.manifest.frames.len()
                ),
            });
        }
        Ok(Some(poses))
    }

    /// The index of the drive that frame `frame` belongs to.
    pub fn drive_of(&self, frame: usize) -> usize {
        self.drives
            .iter()
            .position(|d| d.frames.contains(&frame))
            .unwrap_or(0)
    }

    pub fn summary(&self) -> Summary {
        let mut s = Summary::of(&self.manifest, self.source.as_ref());
        s.warnings = self.warnings.clone();
        s
    }
}
