//! The finished tiles' surfels: what `surfels.ply` holds, and the centres of those
//! some view saw (the elevation metrics). In the page they are held in memory (88
//! bytes a surfel with 9 classes and 24 a centre: 1.6 GB for the 3.7 km `long` at
//! 5 cm). Natively each tile's checkpoint is on disk as soon as the tile finishes,
//! and holds the same surfels, so with `spill_to` set a checkpointed tile keeps only its
//! file's path and surfel count; the model's files are written a tile at a time,
//! each read back from its checkpoint, in the order the tiles finished. The files
//! are the same either way (tests/tiles.rs), and the run's memory no longer grows
//! with the surfels of the road behind it.

use super::checkpoint;
use crate::export::ModelWriter;
use crate::render::Params;
use std::path::PathBuf;

/// What `FinishedModel::each` calls with a tile's surfels and seen centres.
type EachTile<'a> = dyn FnMut(&Params<f32>, &[[f64; 3]]) -> Result<(), String> + 'a;

/// A finished tile's surfels.
enum Part {
    /// The next `surfels` of `held` and `centres` of `held_centres`.
    Held { surfels: usize, centres: usize },
    /// In the checkpoint at this path.
    Spilled { path: PathBuf, surfels: usize },
}

/// The surfels of every finished tile, in the order the tiles finished.
#[derive(Default)]
pub struct FinishedModel {
    held: Params<f32>,
    held_centres: Vec<[f64; 3]>,
    parts: Vec<Part>,
    /// Where the run writes its checkpoints (natively): tiles checkpointed there
    /// are not held.
    pub spill_to: Option<PathBuf>,
}

impl FinishedModel {
    pub fn new(channels: usize) -> Self {
        Self {
            held: Params {
                channels,
                ..Default::default()
            },
            ..Default::default()
        }
    }

    pub fn channels(&self) -> usize {
        self.held.channels
    }

    /// Adds a tile's surfels and seen centres; `checkpoint`: the path of its
    /// checkpoint file, which holds them, when spilling (`spill_to` is set).
    pub fn add(&mut self, p: &Params<f32>, centres: &[[f64; 3]], checkpoint: Option<PathBuf>) {
        match checkpoint.filter(|_| self.spill_to.is_some()) {
            Some(path) => self.parts.push(Part::Spilled {
                path,
                surfels: p.len(),
            }),
            None => {
                let all: Vec<usize> = (0..p.len()).collect();
                super::append(&mut self.held, p, &all, [0.0; 3]);
                self.held_centres.extend_from_slice(centres);
                self.parts.push(Part::Held {
                    surfels: p.len(),
                    centres: centres.len(),
                });
            }
        }
    }

    /// Surfels in all, held or not.
    pub fn len(&self) -> usize {
        self.parts
            .iter()
            .map(|p| match p {
                Part::Held { surfels, .. } => *surfels,
                Part::Spilled { surfels, .. } => *surfels,
            })
            .sum()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The surfels held in memory: all of them unless tiles were spilled.
    pub fn held(&self) -> &Params<f32> {
        &self.held
    }

    /// Tiles whose surfels are in their checkpoints, not in memory.
    pub fn spilled_tiles(&self) -> usize {
        self.parts
            .iter()
            .filter(|p| matches!(p, Part::Spilled { .. }))
            .count()
    }

    /// Writes every tile's surfels into `w`, in order, reading spilled tiles back
    /// from their checkpoints one at a time. `Err` names a checkpoint that cannot
    /// be read.
    pub fn write<W: std::io::Write>(&self, w: &mut ModelWriter<'_, W>) -> Result<(), String> {
        self.each(&mut |p, _| w.add(p))
    }

    /// The seen centres of every tile, in order (spilled tiles' read back; borrowed
    /// when every tile is held, as in the page).
    pub fn centres(&self) -> Result<std::borrow::Cow<'_, [[f64; 3]]>, String> {
        if self.spilled_tiles() == 0 {
            return Ok(std::borrow::Cow::Borrowed(&self.held_centres));
        }
        let mut out = Vec::new();
        self.each(&mut |_, c| {
            out.extend_from_slice(c);
            Ok(())
        })?;
        Ok(std::borrow::Cow::Owned(out))
    }

    /// `f(surfels, centres)` for each tile in order.
    fn each(&self, f: &mut EachTile<'_>) -> Result<(), String> {
        let (mut at, mut at_c) = (0, 0);
        for part in &self.parts {
            match part {
                Part::Held { surfels, centres } => {
                    let mut p = Params {
                        channels: self.held.channels,
                        ..Default::default()
                    };
                    let range: Vec<usize> = (at..at + surfels).collect();
                    super::append(&mut p, &self.held, &range, [0.0; 3]);
                    f(&p, &self.held_centres[at_c..at_c + centres])?;
                    at += surfels;
                    at_c += centres;
                }
                Part::Spilled { path, surfels } => {
                    let bytes = std::fs::read(path).map_err(|e| {
                        format!("cannot read the tile checkpoint {}: {e}", path.display())
                    })?;
                    let (p, c) = checkpoint::decode_model(&bytes)
                        .map_err(|e| format!("{}: {e}", path.display()))?;
                    if p.len() != *surfels {
                        return Err(format!(
                            "{} holds {} surfels, the run finished that tile with {surfels}",
                            path.display(),
                            p.len()
                        ));
                    }
                    f(&p, &c)?;
                }
            }
        }
        Ok(())
    }
}
