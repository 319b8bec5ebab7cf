//! The synthetic world: road surface (field + road materials), parked vehicles as
//! boxes standing on the road, and the sky.

use super::classes::{SKY, VEHICLE};
use super::field::Field;
use super::raycast::{Hit, Scene};
use super::road::{Centreline, RoadSpec};

/// Rays end here (metres); farther surfaces count as background (sky class).
pub const MAX_DISTANCE: f64 = 80.0;

/// An oriented box standing on the ground (a parked car).
#[derive(Clone, Debug)]
pub struct Occluder {
    /// Centre of the footprint in world xy, and its ground height.
    pub centre: [f64; 3],
    pub yaw: f64,
    /// Half length, half width, height.
    pub size: [f64; 3],
    pub albedo: [f64; 3],
}

impl Occluder {
    /// Entry distance and outward normal of the ray `o + τ d`.
    fn intersect(&self, o: [f64; 3], d: [f64; 3]) -> Option<(f64, [f64; 3])> {
        let (c, s) = (self.yaw.cos(), self.yaw.sin());
        let rel = [
            o[0] - self.centre[0],
            o[1] - self.centre[1],
            o[2] - self.centre[2],
        ];
        let lo = [c * rel[0] + s * rel[1], -s * rel[0] + c * rel[1], rel[2]];
        let ld = [c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]];
        let min = [-self.size[0], -self.size[1], -0.3];
        let max = [self.size[0], self.size[1], self.size[2]];
        let (mut t0, mut t1, mut axis, mut sign) = (0.0f64, f64::MAX, 0, 1.0);
        for k in 0..3 {
            if ld[k].abs() < 1e-12 {
                if lo[k] < min[k] || lo[k] > max[k] {
                    return None;
                }
                continue;
            }
            let (a, b) = ((min[k] - lo[k]) / ld[k], (max[k] - lo[k]) / ld[k]);
            let (near, far) = if a < b { (a, b) } else { (b, a) };
            if near > t0 {
                t0 = near;
                axis = k;
                sign = if ld[k] > 0.0 { -1.0 } else { 1.0 };
            }
            t1 = t1.min(far);
        }
        if t0 > t1 || t0 <= 0.0 {
            return None;
        }
        let mut ln = [0.0; 3];
        ln[axis] = sign;
        Some((t0, [c * ln[0] - s * ln[1], s * ln[0] + c * ln[1], ln[2]]))
    }

    /// True when world (x, y) is under the box.
    pub fn covers(&self, x: f64, y: f64) -> bool {
        let (c, s) = (self.yaw.cos(), self.yaw.sin());
        let (dx, dy) = (x - self.centre[0], y - self.centre[1]);
        (c * dx + s * dy).abs() <= self.size[0] && (-s * dx + c * dy).abs() <= self.size[1]
    }
}

pub struct World {
    pub road: RoadSpec,
    pub line: Centreline,
    pub field: Field,
    pub occluders: Vec<Occluder>,
}

impl World {
    pub fn new(road: RoadSpec, cell: f64, occluders_st: &[(f64, f64, f64, [f64; 3])]) -> Self {
        let line = Centreline::new(&road.pieces);
        let field = Field::build(&road, &line, cell);
        let occluders = occluders_st
            .iter()
            .map(|&(s, t, len, albedo)| {
                let (x, y, heading) = line.point(s, t);
                let z = field.height(x, y).unwrap_or(0.0);
                Occluder {
                    centre: [x, y, z],
                    yaw: heading,
                    size: [len / 2.0, 0.9, 1.5],
                    albedo,
                }
            })
            .collect();
        Self {
            road,
            line,
            field,
            occluders,
        }
    }

    /// Albedo and class of the true surface at world (x, y), if inside the world.
    pub fn surface(&self, x: f64, y: f64) -> Option<([f64; 3], u8)> {
        let s = self.field.sample(x, y)?;
        Some(self.road.material(s.s, s.t))
    }
}

impl Scene for World {
    fn hit(&self, o: [f64; 3], d: [f64; 3]) -> Hit {
        let mut best: Option<(f64, usize, [f64; 3])> = None;
        for (k, b) in self.occluders.iter().enumerate() {
            if let Some((t, n)) = b.intersect(o, d) {
                if best.is_none_or(|bb| t < bb.0) {
                    best = Some((t, k, n));
                }
            }
        }
        let limit = best.map_or(MAX_DISTANCE, |b| b.0);
        if let Some(tau) = self.field.intersect(o, d, 0.0, limit) {
            let (x, y) = (o[0] + tau * d[0], o[1] + tau * d[1]);
            if let Some((albedo, class)) = self.surface(x, y) {
                return Hit::Surface {
                    tau,
                    albedo,
                    class,
                    normal: self.field.normal(x, y),
                };
            }
        }
        if let Some((tau, k, normal)) = best {
            return Hit::Surface {
                tau,
                albedo: self.occluders[k].albedo,
                class: VEHICLE,
                normal,
            };
        }
        let e = d[2].clamp(0.0, 1.0);
        let color = [0.78 - 0.4 * e, 0.84 - 0.28 * e, 0.92 - 0.05 * e];
        Hit::Sky { color, class: SKY }
    }
}
