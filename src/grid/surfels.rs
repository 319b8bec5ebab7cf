//! Surfel parameters as a structure of arrays, the layout the GPU buffers use.
//! x and y are fixed on the grid (`Grid`); everything here is learnable or prior.

use super::Grid;

#[derive(Clone, Debug, Default)]
pub struct Surfels {
    /// Elevation (learnable).
    pub z: Vec<f32>,
    /// Linear RGB in 0..1 (learnable).
    pub rgb: Vec<[f32; 3]>,
    /// log(s_u), log(s_v): tangent-plane scales (learnable).
    pub log_scale: Vec<[f32; 2]>,
    /// Opacity logit (learnable).
    pub opacity: Vec<f32>,
    /// Unit quaternion (w, x, y, z) (learnable).
    pub rotation: Vec<[f32; 4]>,
    /// Semantic logits, `classes` per surfel (learnable).
    pub logits: Vec<f32>,
    pub classes: usize,
    /// Pose-consensus elevation ẑ and its confidence q (priors for L_traj).
    pub z_hat: Vec<f32>,
    pub q: Vec<f32>,
}

impl Surfels {
    /// Bytes per surfel for `classes` semantic classes (parameters and priors).
    pub fn bytes_per_surfel(classes: usize) -> u64 {
        4 * (1 + 3 + 2 + 1 + 4 + classes as u64 + 2)
    }

    /// Surfels for every grid vertex: scale 0.6 × spacing (the spacing of its level),
    /// opacity ~1, grey, uniform logits; z, rotation and priors from `init`.
    pub fn new(
        grid: &Grid,
        classes: usize,
        z: &[f32],
        z_hat: &[f32],
        q: &[f32],
        rotation: &[[f32; 4]],
    ) -> Self {
        let n = grid.len();
        let log_scale = grid
            .level
            .iter()
            .map(|&l| {
                let s = (0.6 * grid.resolution / (1 << l) as f64).ln() as f32;
                [s, s]
            })
            .collect();
        Self {
            z: z.to_vec(),
            rgb: vec![[0.5; 3]; n],
            log_scale,
            // logit(0.99): the official code starts at opacity 1.
            opacity: vec![4.6; n],
            rotation: rotation.to_vec(),
            logits: vec![0.0; n * classes],
            classes,
            z_hat: z_hat.to_vec(),
            q: q.to_vec(),
        }
    }

    pub fn len(&self) -> usize {
        self.z.len()
    }

    pub fn is_empty(&self) -> bool {
        self.z.is_empty()
    }
}
