//! Candidates of a view, on the host: the surfels that may pass `project`'s culling
//! box, in increasing surfel order. The GPU passes of a view then work on this list
//! alone: projected surfels, tile counts and view gradients are held per candidate,
//! not per surfel, so a view of a long drive costs memory for what it sees (about 5 %
//! of `nuscenes-like`'s surfels) rather than for the whole model.
//!
//! Why the host can do it: x and y never change (the grid fixes them) and z moves
//! little, so the test runs on the positions known at upload with z widened by
//! `Z_MARGIN` either way: a superset of what `project` keeps, which still applies the
//! exact test. The order is the surfels' own, so pairs reach the stable sort in the
//! same order as when every surfel is projected, and the output is unchanged.

use super::{CullConfig, ViewCamera};

/// A square window of a view from above (the map's chunks) and how far each surfel
/// reaches: a surfel is a candidate when its centre is within `half + reach[i]` of
/// the view's axis in x and y. A window widened by the largest surfel's reach listed,
/// on a model with a few surfels metres wide, most of the model for every chunk
/// (1.76 M surfels, 161 MiB, for a 12.8 m chunk at 5 cm); each surfel's own reach
/// lists only those that touch it.
pub struct Footprints<'a> {
    pub reach: &'a [f32],
    pub half: f32,
}

/// How far (m) a surfel's z may move from its uploaded value and still be found.
pub const Z_MARGIN: f32 = 2.0;

/// Indices of the surfels whose camera-space position, for any z within `Z_MARGIN` of
/// `xyz`'s, can fall inside the culling box (near ≤ depth ≤ far, |x| ≤ half width,
/// |y| ≤ half height). With `fp`, x and y are tested against each surfel's own
/// footprint instead (`Footprints`).
pub fn candidates(
    xyz: &[[f32; 3]],
    cam: &ViewCamera,
    cull: &CullConfig,
    fp: Option<&Footprints>,
) -> Vec<u32> {
    let [r0, r1, r2] = cam.world_to_cam;
    // A margin in z moves camera-space x and depth by at most |r·ẑ| · Z_MARGIN; a
    // centimetre more covers the GPU's rounding.
    let spread = |r: [f32; 4]| r[2].abs() * Z_MARGIN + 0.01;
    let (sx, sy, sz) = (spread(r0), spread(r1), spread(r2));
    let row = |r: [f32; 4], p: [f32; 3]| r[0] * p[0] + r[1] * p[1] + r[2] * p[2] + r[3];
    xyz.iter()
        .enumerate()
        .filter(|&(i, &p)| {
            let (x, depth) = (row(r0, p), row(r2, p));
            let near_far = depth + sz >= cull.near && depth - sz <= cull.far;
            near_far
                && match fp {
                    Some(f) => {
                        let h = f.half + f.reach.get(i).copied().unwrap_or(0.0);
                        x.abs() - sx <= h && row(r1, p).abs() - sy <= h
                    }
                    None => {
                        x.abs() - sx <= cull.half_width
                            && (cull.half_height.is_infinite()
                                || row(r1, p).abs() - sy <= cull.half_height)
                    }
                }
        })
        .map(|(i, _)| i as u32)
        .collect()
}

/// Membership of the candidates for a pass over every surfel: per 32 surfels, the
/// bit mask of those in `cand` and the number of candidates before them, so that
/// surfel i's slot is `before + countOneBits(mask & (bit(i) − 1))`. `cand` must be
/// increasing.
pub fn membership(cand: &[u32], surfels: usize) -> Vec<u32> {
    let words = surfels.div_ceil(32);
    let mut out = vec![0u32; 2 * words];
    for &i in cand {
        out[2 * (i as usize / 32)] |= 1 << (i % 32);
    }
    let mut before = 0;
    for w in 0..words {
        out[2 * w + 1] = before;
        before += out[2 * w].count_ones();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::project::to_cam;
    use crate::render::scene::{road_camera, road_patch};

    #[test]
    fn candidates_hold_every_surfel_the_box_keeps_and_drop_far_ones() {
        let cam = road_camera(64, 48, 8.0);
        let cull = CullConfig {
            near: 1.0,
            far: 12.0,
            half_width: 3.0,
            ..CullConfig::default()
        };
        // A 12 m × 30 m patch: some surfels behind, beside and beyond the box.
        let p = road_patch(60, 150, 0.2, -6.0, -5.0, 1, 3);
        let uploaded: Vec<[f32; 3]> = p.pos.iter().map(|q| q.map(|v| v as f32)).collect();
        let cand = candidates(&uploaded, &cam, &cull, None);
        assert!(cand.windows(2).all(|w| w[0] < w[1]));
        // z moved by up to the margin since upload: still found.
        for dz in [-0.99 * Z_MARGIN as f64, 0.0, 0.99 * Z_MARGIN as f64] {
            for (i, q) in p.pos.iter().enumerate() {
                let pc = to_cam(&cam, [q[0], q[1], q[2] + dz]);
                let kept = pc[2] >= cull.near as f64
                    && pc[2] <= cull.far as f64
                    && pc[0].abs() <= cull.half_width as f64;
                assert!(
                    !kept || cand.binary_search(&(i as u32)).is_ok(),
                    "surfel {i}, dz {dz}"
                );
            }
        }
        assert!(
            cand.len() < p.pos.len() / 2,
            "{} of {}",
            cand.len(),
            p.pos.len()
        );
    }

    #[test]
    fn membership_gives_each_candidate_its_slot() {
        let cand = [1u32, 5, 31, 32, 40, 95];
        let m = membership(&cand, 100);
        for (s, &i) in cand.iter().enumerate() {
            let (mask, before) = (m[2 * (i as usize / 32)], m[2 * (i as usize / 32) + 1]);
            let bit = 1u32 << (i % 32);
            assert!(mask & bit != 0);
            assert_eq!((before + (mask & (bit - 1)).count_ones()) as usize, s);
        }
        assert_eq!(m.iter().step_by(2).map(|w| w.count_ones()).sum::<u32>(), 6);
    }
}
