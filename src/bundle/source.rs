//! Where bundle files come from: a zip archive (in memory, or natively read from its
//! file entry by entry, never whole), natively a folder, or in the page a
//! `LazyStore` that holds only the files the work at hand needs (the page reads
//! them from the dropped file as tiles ask for them). All enforce the same resource
//! limits, so that a hostile bundle (a zip bomb, a path escaping the folder) is
//! refused before anything is inflated.

use super::error::{unsafe_rule, Problem};
use std::collections::{BTreeMap, HashMap};
use std::io::{Cursor, Read, Seek};
use std::sync::{Arc, Mutex};

/// Resource bounds applied while reading a bundle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    /// Largest uncompressed size of one file.
    pub max_file_bytes: u64,
    /// Largest sum of uncompressed sizes over the whole archive.
    pub max_total_bytes: u64,
    /// Largest image width or height.
    pub max_image_side: u32,
    /// Decode every camera image when the bundle is opened (`rogs inspect`, the page's
    /// check of a dropped bundle), so that a truncated or corrupt image is named
    /// before any work; otherwise only headers are read and each image is decoded
    /// when a step uses it.
    pub decode_images: bool,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_file_bytes: 256 << 20,
            max_total_bytes: 16 << 30,
            max_image_side: 8192,
            decode_images: false,
        }
    }
}

/// Largest side of a ground-truth raster: it spans the whole drive (a 3.7 km drive
/// at 5 cm is 74 000 px long), where a camera image is bounded by `max_image_side`.
pub const TRUTH_MAX_SIDE: u32 = 1 << 17;
/// Largest ground-truth file (the elevation raster of a 3.7 km drive is 0.6 GB).
pub const TRUTH_MAX_FILE_BYTES: u64 = 4 << 30;

impl Limits {
    /// The limits for the ground truth's rasters.
    pub fn for_truth(&self) -> Limits {
        Limits {
            max_image_side: self.max_image_side.max(TRUTH_MAX_SIDE),
            max_file_bytes: self.max_file_bytes.max(TRUTH_MAX_FILE_BYTES),
            ..*self
        }
    }
}

/// True when `path` is a relative '/'-separated path that cannot leave the bundle.
pub fn is_safe_path(path: &str) -> bool {
    !path.is_empty()
        && !path.starts_with('/')
        && !path.contains('\\')
        && !path.contains(':')
        && !path.contains('\0')
        && path
            .split('/')
            .all(|c| !c.is_empty() && c != ".." && c != ".")
}

/// The entry names of a zip's central directory, in order, twins included (`None`
/// when the directory cannot be found; the zip reader then says why). Zip64
/// directories are not walked.
fn central_names(r: &mut dyn ReadSeek) -> Option<Vec<String>> {
    use std::io::SeekFrom;
    let len = r.seek(SeekFrom::End(0)).ok()?;
    let tail_len = len.min(65_557);
    r.seek(SeekFrom::Start(len - tail_len)).ok()?;
    let mut tail = vec![0u8; tail_len as usize];
    r.read_exact(&mut tail).ok()?;
    let e = (0..tail.len().saturating_sub(21))
        .rev()
        .find(|&i| tail[i..i + 4] == [0x50, 0x4b, 0x05, 0x06])?;
    let u16_at = |b: &[u8], o: usize| u16::from_le_bytes([b[o], b[o + 1]]) as usize;
    let u32_at = |b: &[u8], o: usize| u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
    let (count, size, offset) = (
        u16_at(&tail, e + 10),
        u32_at(&tail, e + 12),
        u32_at(&tail, e + 16),
    );
    if count == 0xffff || offset == u32::MAX || u64::from(offset) + u64::from(size) > len {
        return None;
    }
    r.seek(SeekFrom::Start(offset.into())).ok()?;
    let mut cd = vec![0u8; size as usize];
    r.read_exact(&mut cd).ok()?;
    let mut names = Vec::with_capacity(count);
    let mut p = 0;
    for _ in 0..count {
        if p + 46 > cd.len() || cd[p..p + 4] != [0x50, 0x4b, 0x01, 0x02] {
            return None;
        }
        let (n, x, c) = (
            u16_at(&cd, p + 28),
            u16_at(&cd, p + 30),
            u16_at(&cd, p + 32),
        );
        let name = cd.get(p + 46..p + 46 + n)?;
        names.push(String::from_utf8_lossy(name).into_owned());
        p += 46 + n + x + c;
    }
    r.seek(SeekFrom::Start(0)).ok()?;
    Some(names)
}

/// A readable set of named files.
pub trait Source: Send + Sync {
    /// Uncompressed size, or `None` when the file is absent.
    fn size(&self, path: &str) -> Option<u64>;
    /// The whole file, refusing it past the limits.
    fn read(&self, path: &str, limits: &Limits) -> Result<Vec<u8>, Problem>;
    /// Files over `max_file_bytes` but within the truth's limit (allowed only for
    /// the truth's rasters; validation refuses the others).
    fn oversize(&self) -> Vec<(String, u64)> {
        Vec::new()
    }
}

fn too_large(path: &str, size: u64, limits: &Limits) -> Result<(), Problem> {
    if size > limits.max_file_bytes {
        return Err(Problem::FileTooLarge {
            path: path.into(),
            size,
            limit: limits.max_file_bytes,
        });
    }
    Ok(())
}

/// The checks every archive's table of entries gets, before anything is inflated:
/// safe names, each entry and the total within the limits. Entries over the file
/// limit but within the truth's are set aside (`oversize`) for validation, which
/// knows which files are the truth's.
#[derive(Default)]
struct EntryTable {
    problems: Vec<Problem>,
    total: u64,
    oversize: Vec<(String, u64)>,
}

impl EntryTable {
    /// Checks one entry; false when its name is refused.
    fn entry(&mut self, name: &str, size: u64, limits: &Limits) -> bool {
        if !is_safe_path(name) {
            self.problems.push(Problem::UnsafeEntry {
                rule: unsafe_rule(name),
                path: name.into(),
            });
            return false;
        }
        self.total = self.total.saturating_add(size);
        if size > limits.max_file_bytes {
            self.oversize.push((name.into(), size));
        }
        if let Err(p) = too_large(name, size, &limits.for_truth()) {
            self.problems.push(p);
        }
        true
    }

    /// The oversize entries; the problems found are added to `problems`.
    fn finish(mut self, limits: &Limits, problems: &mut Vec<Problem>) -> Vec<(String, u64)> {
        if self.total > limits.max_total_bytes {
            self.problems.push(Problem::FileTooLarge {
                path: "(whole archive)".into(),
                size: self.total,
                limit: limits.max_total_bytes,
            });
        }
        problems.append(&mut self.problems);
        self.oversize
    }
}

/// What a zip archive can be read from: bytes in memory, or natively its file.
pub trait ReadSeek: Read + Seek + Send {}
impl<T: Read + Seek + Send> ReadSeek for T {}

/// A zip archive, read one entry at a time.
pub struct ZipSource {
    archive: Mutex<zip::ZipArchive<Box<dyn ReadSeek>>>,
    oversize: Vec<(String, u64)>,
}

impl ZipSource {
    /// Opens an archive held in memory.
    pub fn new(bytes: Vec<u8>, limits: &Limits) -> Result<Self, Vec<Problem>> {
        Self::from_reader(Box::new(Cursor::new(bytes)), limits)
    }

    /// Opens the archive and checks every entry name and the declared sizes. Only
    /// the central directory is read; entries are inflated when they are read.
    pub fn from_reader(
        mut reader: Box<dyn ReadSeek>,
        limits: &Limits,
    ) -> Result<Self, Vec<Problem>> {
        // The zip reader keeps one entry per name: find a name's twins first.
        let twins = central_names(reader.as_mut())
            .map(|names| {
                let mut seen = std::collections::HashSet::new();
                let mut twins: Vec<String> = names
                    .into_iter()
                    .filter(|n| !seen.insert(n.clone()))
                    .collect();
                twins.dedup();
                twins
            })
            .unwrap_or_default();
        let mut archive =
            zip::ZipArchive::new(reader).map_err(|e| vec![Problem::NotZip(e.to_string())])?;
        let mut problems: Vec<Problem> = twins
            .into_iter()
            .map(|path| Problem::Unreadable {
                path: path.trim_end_matches('/').to_string(),
                reason: "the archive holds two entries of this name; keep one".into(),
            })
            .collect();
        let mut table = EntryTable::default();
        for i in 0..archive.len() {
            let entry = match archive.by_index_raw(i) {
                Ok(e) => e,
                Err(e) => {
                    problems.push(Problem::NotZip(e.to_string()));
                    continue;
                }
            };
            let name = match entry.name() {
                Ok(n) => n.trim_end_matches('/').to_string(),
                Err(e) => {
                    problems.push(Problem::NotZip(format!("entry {i}: {e}")));
                    continue;
                }
            };
            if table.entry(&name, entry.size(), limits) && entry.encrypted() {
                problems.push(Problem::Unreadable {
                    path: name.clone(),
                    reason: "the entry is encrypted; bundles must be unencrypted zips".into(),
                });
            }
        }
        let oversize = table.finish(limits, &mut problems);
        if problems.is_empty() {
            Ok(Self {
                archive: Mutex::new(archive),
                oversize,
            })
        } else {
            Err(problems)
        }
    }
}

impl Source for ZipSource {
    fn oversize(&self) -> Vec<(String, u64)> {
        self.oversize.clone()
    }

    fn size(&self, path: &str) -> Option<u64> {
        let mut a = self.archive.lock().ok()?;
        let f = a.by_name(path).ok()?;
        Some(f.size())
    }

    fn read(&self, path: &str, limits: &Limits) -> Result<Vec<u8>, Problem> {
        let unreadable = |reason: String| Problem::Unreadable {
            path: path.into(),
            reason,
        };
        let mut a = self
            .archive
            .lock()
            .map_err(|_| unreadable("archive lock poisoned".into()))?;
        let f = a.by_name(path).map_err(|e| unreadable(e.to_string()))?;
        too_large(path, f.size(), limits)?;
        // The declared size may lie: never inflate more than the limit, and reserve
        // no more than deflate can make of the stored bytes (1 032:1) nor 64 MiB up
        // front (a damaged header declaring 4 GiB once reserved all of it; fuzzing
        // found it). Past that the buffer grows with what really inflates.
        let hint = f
            .size()
            .min(limits.max_file_bytes)
            .min(f.compressed_size().saturating_mul(1032))
            .min(64 << 20);
        let mut out = Vec::with_capacity(hint as usize);
        f.take(limits.max_file_bytes + 1)
            .read_to_end(&mut out)
            .map_err(|e| unreadable(e.to_string()))?;
        too_large(path, out.len() as u64, limits)?;
        Ok(out)
    }
}

/// A bundle unpacked into a folder (native only).
#[cfg(not(target_arch = "wasm32"))]
pub struct DirSource {
    pub root: std::path::PathBuf,
}

#[cfg(not(target_arch = "wasm32"))]
impl Source for DirSource {
    fn size(&self, path: &str) -> Option<u64> {
        if !is_safe_path(path) {
            return None;
        }
        let full = self.root.join(path);
        // A symbolic link is followed only while it stays inside the bundle.
        let inside = std::fs::canonicalize(&full)
            .ok()
            .zip(std::fs::canonicalize(&self.root).ok())
            .is_some_and(|(f, r)| f.starts_with(r));
        if !inside {
            return None;
        }
        let m = std::fs::metadata(full).ok()?;
        m.is_file().then_some(m.len())
    }

    fn read(&self, path: &str, limits: &Limits) -> Result<Vec<u8>, Problem> {
        let size = self.size(path).ok_or_else(|| Problem::Unreadable {
            path: path.into(),
            reason: "no such file".into(),
        })?;
        too_large(path, size, limits)?;
        std::fs::read(self.root.join(path)).map_err(|e| Problem::Unreadable {
            path: path.into(),
            reason: e.to_string(),
        })
    }
}

/// The files of a bundle held only while they are needed: its table of entries
/// (name → uncompressed size) is known from the start, the bytes arrive through
/// `provide` and leave through `retain`. Reading a file that is not held is
/// `Problem::NotLoaded`, never a silent empty file. The page keeps one per dropped
/// bundle and fills it, tile by tile, from the file on disk (docs/ARCHITECTURE.md).
#[derive(Default)]
pub struct LazyStore {
    sizes: BTreeMap<String, u64>,
    oversize: Vec<(String, u64)>,
    held: Mutex<HashMap<String, Arc<Vec<u8>>>>,
}

impl LazyStore {
    /// A store over the archive's entries (names and uncompressed sizes), checked
    /// as a zip's are: safe names, each and the total within the limits.
    pub fn new(entries: Vec<(String, u64)>, limits: &Limits) -> Result<Self, Vec<Problem>> {
        let mut problems = Vec::new();
        let mut sizes = BTreeMap::new();
        let mut table = EntryTable::default();
        for (name, size) in entries {
            let name = name.trim_end_matches('/').to_string();
            if name.is_empty() || !table.entry(&name, size, limits) {
                continue;
            }
            if sizes.insert(name.clone(), size).is_some() {
                problems.push(Problem::Unreadable {
                    path: name,
                    reason: "the archive holds two entries of this name; keep one".into(),
                });
            }
        }
        let oversize = table.finish(limits, &mut problems);
        if problems.is_empty() {
            Ok(Self {
                sizes,
                oversize,
                held: Mutex::default(),
            })
        } else {
            Err(problems)
        }
    }

    /// Hands in a file's bytes (as the archive holds them once inflated).
    pub fn provide(&self, path: &str, bytes: Vec<u8>) -> Result<(), Problem> {
        let expected = self.sizes.get(path).copied();
        match expected {
            None => Err(Problem::Unreadable {
                path: path.into(),
                reason: "not an entry of the archive".into(),
            }),
            Some(n) if n != bytes.len() as u64 => Err(Problem::Unreadable {
                path: path.into(),
                reason: format!(
                    "{} bytes read, the archive's directory says {n} (damaged archive?)",
                    bytes.len()
                ),
            }),
            Some(_) => {
                if let Ok(mut h) = self.held.lock() {
                    h.insert(path.into(), Arc::new(bytes));
                }
                Ok(())
            }
        }
    }

    /// True when `path` is held now.
    pub fn holds(&self, path: &str) -> bool {
        self.held.lock().is_ok_and(|h| h.contains_key(path))
    }

    /// Drops every held file that `keep` does not name.
    pub fn retain(&self, keep: &std::collections::HashSet<&str>) {
        if let Ok(mut h) = self.held.lock() {
            h.retain(|k, _| keep.contains(k.as_str()));
        }
    }

    /// Uncompressed bytes of every entry.
    pub fn total_bytes(&self) -> u64 {
        self.sizes.values().sum()
    }

    /// Bytes held now.
    pub fn held_bytes(&self) -> u64 {
        self.held
            .lock()
            .map_or(0, |h| h.values().map(|b| b.len() as u64).sum())
    }
}

impl Source for Arc<LazyStore> {
    fn oversize(&self) -> Vec<(String, u64)> {
        self.oversize.clone()
    }

    fn size(&self, path: &str) -> Option<u64> {
        self.sizes.get(path).copied()
    }

    fn read(&self, path: &str, limits: &Limits) -> Result<Vec<u8>, Problem> {
        let size = self.size(path).ok_or_else(|| Problem::Unreadable {
            path: path.into(),
            reason: "no such file".into(),
        })?;
        too_large(path, size, limits)?;
        let held = self.held.lock().ok().and_then(|h| h.get(path).cloned());
        match held {
            Some(b) => Ok(b.as_ref().clone()),
            None => Err(Problem::NotLoaded { path: path.into() }),
        }
    }
}
