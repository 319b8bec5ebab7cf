//! The index map: lattice coordinates → surfel id, stored in 64×64 tiles that exist
//! only where the corridor is. A 3.7 km loop costs memory for its corridor, not for
//! its bounding box, and a neighbour query is one hash lookup and one array read.

use crate::spatial::CellMap;

const TILE: i32 = 64;
pub const EMPTY: u32 = u32::MAX;

#[derive(Default, Clone)]
pub struct IndexMap {
    tiles: CellMap<(i32, i32), Box<[u32]>>,
}

fn split(i: i32, j: i32) -> ((i32, i32), usize) {
    let (ti, tj) = (i.div_euclid(TILE), j.div_euclid(TILE));
    let (li, lj) = (i.rem_euclid(TILE), j.rem_euclid(TILE));
    ((ti, tj), (lj * TILE + li) as usize)
}

impl IndexMap {
    pub fn get(&self, i: i32, j: i32) -> Option<u32> {
        let (t, k) = split(i, j);
        self.tiles
            .get(&t)
            .map(|tile| tile[k])
            .filter(|&v| v != EMPTY)
    }

    pub fn set(&mut self, i: i32, j: i32, v: u32) {
        let (t, k) = split(i, j);
        self.tiles
            .entry(t)
            .or_insert_with(|| vec![EMPTY; (TILE * TILE) as usize].into_boxed_slice())[k] = v;
    }

    pub fn tile_count(&self) -> usize {
        self.tiles.len()
    }

    pub fn bytes(&self) -> usize {
        self.tiles.len() * (TILE * TILE) as usize * 4
    }

    /// Every set entry as (i, j, value), tile by tile (sorted), row-major within a
    /// tile: spatially coherent, and deterministic.
    pub fn entries(&self) -> Vec<(i32, i32, u32)> {
        let mut keys: Vec<_> = self.tiles.keys().copied().collect();
        keys.sort_by_key(|&(ti, tj)| (tj, ti));
        let mut out = Vec::new();
        for (ti, tj) in keys {
            let tile = &self.tiles[&(ti, tj)];
            for (k, &v) in tile.iter().enumerate() {
                if v != EMPTY {
                    let (li, lj) = (k as i32 % TILE, k as i32 / TILE);
                    out.push((ti * TILE + li, tj * TILE + lj, v));
                }
            }
        }
        out
    }
}
