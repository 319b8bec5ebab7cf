//! Where bundle files come from: a zip held in memory (works in wasm) or, natively, a
//! folder. Both enforce the same resource limits, so that a hostile bundle (a zip
//! bomb, a path escaping the folder) is refused before anything is inflated.

use super::error::Problem;
use std::io::{Cursor, Read};
use std::sync::Mutex;

/// Resource bounds applied while reading a bundle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    /// Largest uncompressed size of one file.
    pub max_file_bytes: u64,
    /// Largest sum of uncompressed sizes over the whole archive.
    pub max_total_bytes: u64,
    /// Largest image width or height.
    pub max_image_side: u32,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_file_bytes: 256 << 20,
            max_total_bytes: 16 << 30,
            max_image_side: 8192,
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

/// A readable set of named files.
pub trait Source: Send + Sync {
    /// Uncompressed size, or `None` when the file is absent.
    fn size(&self, path: &str) -> Option<u64>;
    /// The whole file, refusing it past the limits.
    fn read(&self, path: &str, limits: &Limits) -> Result<Vec<u8>, Problem>;
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

/// A zip archive in memory.
pub struct ZipSource {
    archive: Mutex<zip::ZipArchive<Cursor<Vec<u8>>>>,
}

impl ZipSource {
    /// Opens the archive and checks every entry name and the declared sizes.
    pub fn new(bytes: Vec<u8>, limits: &Limits) -> Result<Self, Vec<Problem>> {
        let mut archive = zip::ZipArchive::new(Cursor::new(bytes))
            .map_err(|e| vec![Problem::NotZip(e.to_string())])?;
        let mut problems = Vec::new();
        let mut total: u64 = 0;
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
            if !is_safe_path(&name) {
                problems.push(Problem::UnsafeEntry { path: name });
                continue;
            }
            total = total.saturating_add(entry.size());
            if let Err(p) = too_large(&name, entry.size(), limits) {
                problems.push(p);
            }
        }
        if total > limits.max_total_bytes {
            problems.push(Problem::FileTooLarge {
                path: "(whole archive)".into(),
                size: total,
                limit: limits.max_total_bytes,
            });
        }
        if problems.is_empty() {
            Ok(Self {
                archive: Mutex::new(archive),
            })
        } else {
            Err(problems)
        }
    }
}

impl Source for ZipSource {
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
        // The declared size may lie: never inflate more than the limit.
        let mut out = Vec::with_capacity(f.size().min(limits.max_file_bytes) as usize);
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
        let m = std::fs::metadata(self.root.join(path)).ok()?;
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
