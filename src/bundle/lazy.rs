//! The files of one or more lazily read bundles (the drives of one map), routed as
//! the merged bundle names them (`driveK/…` when there are several drives). The page
//! opens a dropped bundle by its zip's directory and keeps a `LazyStore` per drive;
//! before each unit of work the run says which files it will read, the ones missing
//! are fetched and checked, and the rest are dropped (`tiles::files`).

use super::{validate_views, Bundle, LazyStore, Problem};
use std::collections::HashSet;
use std::sync::Arc;

/// One lazily read store per drive, in the order the drives were merged.
pub struct LazyFiles {
    pub stores: Vec<Arc<LazyStore>>,
}

impl LazyFiles {
    /// The drive and the path within it of a file as the (merged) bundle names it.
    pub fn route<'a>(&self, path: &'a str) -> Option<(usize, &'a str)> {
        if self.stores.len() == 1 {
            return Some((0, path));
        }
        let (k, rest) = path.strip_prefix("drive")?.split_once('/')?;
        let k: usize = k.parse().ok()?;
        (k < self.stores.len()).then_some((k, rest))
    }

    /// The files of `wanted` not held now, as (drive, path within the drive).
    pub fn missing(&self, wanted: &[String]) -> Vec<(usize, String)> {
        wanted
            .iter()
            .filter_map(|p| self.route(p))
            .filter(|(k, p)| !self.stores[*k].holds(p))
            .map(|(k, p)| (k, p.to_string()))
            .collect()
    }

    /// Drops every held file that `wanted` does not name.
    pub fn retain(&self, wanted: &[String]) {
        for (k, s) in self.stores.iter().enumerate() {
            let keep: HashSet<&str> = wanted
                .iter()
                .filter_map(|p| self.route(p))
                .filter(|(d, _)| *d == k)
                .map(|(_, p)| p)
                .collect();
            s.retain(&keep);
        }
    }

    pub fn provide(&self, drive: usize, path: &str, bytes: Vec<u8>) -> Result<(), Problem> {
        match self.stores.get(drive) {
            Some(s) => s.provide(path, bytes),
            None => Err(Problem::Unreadable {
                path: path.into(),
                reason: format!("no drive {drive}"),
            }),
        }
    }

    /// Bytes held now, over every drive.
    pub fn held_bytes(&self) -> u64 {
        self.stores.iter().map(|s| s.held_bytes()).sum()
    }

    /// Checks the content of the views (and truth) among `fetched` as opening an
    /// eagerly read bundle would have: each file once, when it arrives.
    pub fn check(&self, b: &Bundle, fetched: &[(usize, String)]) -> Vec<Problem> {
        let merged = self.stores.len() > 1;
        let names: HashSet<String> = fetched
            .iter()
            .map(|(k, p)| {
                if merged {
                    format!("drive{k}/{p}")
                } else {
                    p.clone()
                }
            })
            .collect();
        let m = &b.manifest;
        let views: Vec<(usize, usize)> = m
            .frames
            .iter()
            .enumerate()
            .flat_map(|(f, fr)| (0..fr.views.len()).map(move |k| (f, k)))
            .filter(|&(f, k)| b.view_files(f, k).iter().any(|p| names.contains(*p)))
            .collect();
        let truth = m
            .ground_truth
            .as_ref()
            .is_some_and(|gt| names.contains(&gt.rgb));
        validate_views(m, b.source(), &b.limits, &views, truth, &|p| {
            names.contains(p)
        })
    }
}
