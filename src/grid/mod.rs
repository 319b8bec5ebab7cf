//! Stage 2: the corridor meshgrid. Surfels sit on the vertices of a square lattice in
//! the world xy-plane, kept only within a half-width of the trajectory polyline.
//!
//! Coordinates are on a *fine* lattice of half the base spacing: base vertices have
//! even coordinates, vertices added by adaptive refinement odd ones, so one index map
//! serves both levels and shared vertices are never duplicated.

mod index;
pub mod surfels;

pub use index::IndexMap;
pub use surfels::Surfels;

use thiserror::Error;

#[derive(Clone, Debug, PartialEq)]
pub struct GridConfig {
    /// Base spacing in metres (the paper: 0.05).
    pub resolution: f64,
    /// Corridor half-width around the trajectory, metres.
    pub half_width: f64,
    /// Refuse grids whose surfels would need more than this many bytes.
    pub memory_budget: u64,
}

impl Default for GridConfig {
    fn default() -> Self {
        Self {
            resolution: 0.05,
            half_width: 8.0,
            memory_budget: 2 << 30,
        }
    }
}

#[derive(Debug, Error, PartialEq)]
pub enum GridError {
    #[error("the trajectory has fewer than 2 distinct positions; a corridor needs a path")]
    NoPath,
    #[error(
        "the grid would have {surfels} surfels needing {bytes} bytes ({mib} MiB), over the budget of {budget} bytes; \
         use a coarser resolution (now {resolution} m) or a narrower corridor (now {half_width} m)",
        mib = bytes >> 20
    )]
    OverBudget {
        surfels: u64,
        bytes: u64,
        budget: u64,
        resolution: f64,
        half_width: f64,
    },
    #[error("resolution {0} m and half-width {1} m must be positive and finite")]
    BadConfig(f64, f64),
}

/// An axis-aligned rectangle in the world xy-plane, metres: `min` inclusive, `max`
/// exclusive (a map tile, or a tile widened by its overlap).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Rect {
    pub min: [f64; 2],
    pub max: [f64; 2],
}

impl Rect {
    pub fn contains(&self, p: [f64; 2]) -> bool {
        p[0] >= self.min[0] && p[0] < self.max[0] && p[1] >= self.min[1] && p[1] < self.max[1]
    }

    /// The rectangle widened by `m` metres on every side.
    pub fn grow(&self, m: f64) -> Rect {
        Rect {
            min: [self.min[0] - m, self.min[1] - m],
            max: [self.max[0] + m, self.max[1] + m],
        }
    }

    /// Squared distance from `p` to the rectangle (0 inside).
    pub fn dist2(&self, p: [f64; 2]) -> f64 {
        let d = |k: usize| (self.min[k] - p[k]).max(p[k] - self.max[k]).max(0.0);
        d(0).powi(2) + d(1).powi(2)
    }
}

/// The surfel lattice: positions and the index map.
#[derive(Clone)]
pub struct Grid {
    /// World xy of fine-lattice vertex (0, 0).
    pub origin: [f64; 2],
    /// Base spacing (fine spacing is half of it).
    pub resolution: f64,
    /// Fine-lattice coordinates of each surfel.
    pub coords: Vec<[i32; 2]>,
    /// 0 for base vertices, 1 for vertices added by refinement.
    pub level: Vec<u8>,
    pub index: IndexMap,
}

/// Squared distance from p to segment ab in the plane.
pub fn dist2_segment(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let w = if len2 > 0.0 {
        (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p[0] - a[0] - w * dx).powi(2) + (p[1] - a[1] - w * dy).powi(2)
}

impl Grid {
    /// The base lattice vertices within `half_width` of the polyline through `path`.
    /// `bytes_per_surfel` sizes the memory check made before anything per surfel is
    /// allocated.
    pub fn corridor(
        path: &[[f64; 2]],
        cfg: &GridConfig,
        bytes_per_surfel: u64,
    ) -> Result<Self, GridError> {
        Self::corridor_of(&[path], cfg, bytes_per_surfel, None)
    }

    /// The base lattice vertices within `half_width` of any of the polylines `paths`
    /// (one per drive: no corridor joins the end of one drive to the start of the
    /// next), kept only inside `clip` (a world rectangle, a map tile) when given.
    /// The lattice's origin depends on the paths only, never on `clip`, so the grids
    /// of neighbouring tiles share their vertices where they overlap.
    pub fn corridor_of(
        paths: &[&[[f64; 2]]],
        cfg: &GridConfig,
        bytes_per_surfel: u64,
        clip: Option<Rect>,
    ) -> Result<Self, GridError> {
        let (res, hw) = (cfg.resolution, cfg.half_width);
        if !(res > 0.0 && hw > 0.0 && res.is_finite() && hw.is_finite()) {
            return Err(GridError::BadConfig(res, hw));
        }
        let mut polylines: Vec<Vec<[f64; 2]>> = Vec::new();
        for path in paths {
            let mut pts: Vec<[f64; 2]> = Vec::new();
            for p in path.iter() {
                if pts
                    .last()
                    .is_none_or(|q| (q[0] - p[0]).hypot(q[1] - p[1]) > 1e-6)
                {
                    pts.push(*p);
                }
            }
            if pts.len() >= 2 {
                polylines.push(pts);
            }
        }
        if polylines.is_empty() {
            return Err(GridError::NoPath);
        }
        // Origin on a multiple of the spacing so that grids of overlapping chunks align.
        let all = || polylines.iter().flatten();
        let x0 = all().map(|p| p[0]).fold(f64::MAX, f64::min) - hw;
        let y0 = all().map(|p| p[1]).fold(f64::MAX, f64::min) - hw;
        let origin = [(x0 / res).floor() * res, (y0 / res).floor() * res];
        let base = |v: f64, o: f64| ((v - o) / res).round() as i32;
        let mut marks = IndexMap::default();
        let mut count: u64 = 0;
        for s in polylines.iter().flat_map(|p| p.windows(2)) {
            let (a, b) = (s[0], s[1]);
            let (mut i0, mut i1) = (
                base(a[0].min(b[0]) - hw, origin[0]) - 1,
                base(a[0].max(b[0]) + hw, origin[0]) + 1,
            );
            let (mut j0, mut j1) = (
                base(a[1].min(b[1]) - hw, origin[1]) - 1,
                base(a[1].max(b[1]) + hw, origin[1]) + 1,
            );
            if let Some(c) = clip {
                // Vertices with x in [min, max), y in [min, max): each tile's own.
                i0 = i0.max(((c.min[0] - origin[0]) / res).ceil() as i32);
                i1 = i1.min(((c.max[0] - origin[0]) / res).ceil() as i32 - 1);
                j0 = j0.max(((c.min[1] - origin[1]) / res).ceil() as i32);
                j1 = j1.min(((c.max[1] - origin[1]) / res).ceil() as i32 - 1);
            }
            for j in j0.max(0)..=j1 {
                for i in i0.max(0)..=i1 {
                    let p = [origin[0] + i as f64 * res, origin[1] + j as f64 * res];
                    if dist2_segment(p, a, b) <= hw * hw && marks.get(2 * i, 2 * j).is_none() {
                        marks.set(2 * i, 2 * j, 0);
                        count += 1;
                    }
                }
            }
        }
        let bytes = count * bytes_per_surfel + marks.bytes() as u64;
        if bytes > cfg.memory_budget {
            return Err(GridError::OverBudget {
                surfels: count,
                bytes,
                budget: cfg.memory_budget,
                resolution: res,
                half_width: hw,
            });
        }
        let mut grid = Grid {
            origin,
            resolution: res,
            coords: Vec::new(),
            level: Vec::new(),
            index: IndexMap::default(),
        };
        for (i, j, _) in marks.entries() {
            grid.insert(i, j, 0);
        }
        Ok(grid)
    }

    pub fn len(&self) -> usize {
        self.coords.len()
    }

    pub fn is_empty(&self) -> bool {
        self.coords.is_empty()
    }

    /// Fine-lattice spacing.
    pub fn fine(&self) -> f64 {
        self.resolution * 0.5
    }

    /// World xy of fine-lattice coordinates.
    pub fn xy_of(&self, i: i32, j: i32) -> [f64; 2] {
        [
            self.origin[0] + i as f64 * self.fine(),
            self.origin[1] + j as f64 * self.fine(),
        ]
    }

    pub fn xy(&self, k: usize) -> [f64; 2] {
        let c = self.coords[k];
        self.xy_of(c[0], c[1])
    }

    /// Adds a surfel at fine coordinates (i, j) unless one is there; returns its id.
    pub fn insert(&mut self, i: i32, j: i32, level: u8) -> u32 {
        if let Some(k) = self.index.get(i, j) {
            return k;
        }
        let k = self.coords.len() as u32;
        self.coords.push([i, j]);
        self.level.push(level);
        self.index.set(i, j, k);
        k
    }

    /// The 4-neighbours of surfel k: the nearest surfel along ±x and ±y at the finest
    /// spacing present (1 fine step, else 2 = one base step).
    pub fn neighbours4(&self, k: usize) -> impl Iterator<Item = u32> + '_ {
        let [i, j] = self.coords[k];
        [(1, 0), (-1, 0), (0, 1), (0, -1)]
            .into_iter()
            .filter_map(move |(di, dj)| {
                self.index
                    .get(i + di, j + dj)
                    .or_else(|| self.index.get(i + 2 * di, j + 2 * dj))
            })
    }

    /// The 8-neighbours (4-neighbours plus diagonals), same spacing rule.
    pub fn neighbours8(&self, k: usize) -> impl Iterator<Item = u32> + '_ {
        let [i, j] = self.coords[k];
        [
            (1, 0),
            (-1, 0),
            (0, 1),
            (0, -1),
            (1, 1),
            (1, -1),
            (-1, 1),
            (-1, -1),
        ]
        .into_iter()
        .filter_map(move |(di, dj)| {
            self.index
                .get(i + di, j + dj)
                .or_else(|| self.index.get(i + 2 * di, j + 2 * dj))
        })
    }

    /// Base cells (lower-left base vertex in fine coordinates) whose 4 corners exist.
    pub fn base_cells(&self) -> Vec<[i32; 2]> {
        let mut cells: Vec<[i32; 2]> = self
            .coords
            .iter()
            .zip(&self.level)
            .filter(|(c, &l)| {
                l == 0
                    && self.index.get(c[0] + 2, c[1]).is_some()
                    && self.index.get(c[0], c[1] + 2).is_some()
                    && self.index.get(c[0] + 2, c[1] + 2).is_some()
            })
            .map(|(c, _)| *c)
            .collect();
        cells.sort_by_key(|c| (c[1], c[0]));
        cells
    }
}
