//! One tile of a plan: the square of the world it trains, the frames near it and the
//! views that see it. A plain description, so that a `Session` can be built for a
//! tile without knowing how tiles are planned or run.

use crate::grid::Rect;

/// One tile of a plan.
#[derive(Clone, Debug)]
pub struct Tile {
    /// Lattice index (core = [i·size, (i+1)·size) × [j·size, (j+1)·size)).
    pub id: [i64; 2],
    pub core: Rect,
    /// The core widened by the overlap: the surfels this tile trains.
    pub rect: Rect,
    /// Frames whose vehicle is near enough to see the rect (LiDAR, colours).
    pub near_frames: Vec<bool>,
    /// (frame, view) of every view that sees some of the tile's corridor, sorted.
    pub views: Vec<(usize, usize)>,
    /// Scene extent of the tile (the z learning rate's scale), metres.
    pub extent: f32,
}

impl Tile {
    /// `x3_y-2`: used in messages, reports and file names.
    pub fn name(&self) -> String {
        format!("x{}_y{}", self.id[0], self.id[1])
    }

    pub fn sees(&self, frame: usize, view: usize) -> bool {
        self.views.binary_search(&(frame, view)).is_ok()
    }
}
