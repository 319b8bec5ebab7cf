//! The surfel model as a binary PLY in the layout of 3D Gaussian splatting files
//! (x y z, normals, f_dc_0..2, opacity, scale_0..2 as logs, rot_0..3 as w x y z), so
//! that common splat viewers open it. Surfels are flat: scale_2 is a tiny constant.

use crate::render::Params;

/// SH degree-0 constant: colour = 0.5 + C0 · f_dc.
const C0: f32 = 0.282_094_8;
/// log of the normal-axis scale written for flat surfels (0.1 mm).
const FLAT_LOG_SCALE: f32 = -9.21;

/// Which axis is up in a written PLY.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Up {
    /// The world frame as it is: x east, y north, z up (GIS tools, the map's frame).
    #[default]
    Z,
    /// Rotated −90° about x for splat viewers that expect y up: (x, y, z) → (x, z, −y).
    Y,
}

impl std::str::FromStr for Up {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "z" => Ok(Up::Z),
            "y" => Ok(Up::Y),
            _ => Err(format!("unknown up axis {s:?}; expected z or y")),
        }
    }
}

/// Rotates a vector from the world frame into the written frame.
fn turn(up: Up, v: [f32; 3]) -> [f32; 3] {
    match up {
        Up::Z => v,
        Up::Y => [v[0], v[2], -v[1]],
    }
}

/// PLY bytes of `p`; positions are local (world − `origin`), recorded in a comment with
/// the up axis. `colours`: one RGB per surfel instead of the learnt colours (the class
/// colours of `surfels_semantic.ply`).
pub fn surfels_ply(
    p: &Params<f32>,
    origin: [f64; 3],
    up: Up,
    colours: Option<&[[u8; 3]]>,
    frame: &str,
) -> Vec<u8> {
    let mut out = header(p.len(), origin, up, frame).into_bytes();
    out.reserve(p.len() * PROPS.len() * 4);
    push_rows(&mut out, p, up, colours);
    out
}

/// The properties of a row, in order.
const PROPS: [&str; 17] = [
    "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
    "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
];

/// The header of a PLY of `count` surfels (`push_rows` writes them): a model written
/// a tile at a time gives the same file as one written whole.
pub fn header(count: usize, origin: [f64; 3], up: Up, frame: &str) -> String {
    let axes = match up {
        Up::Z => "comment up z: x east, y north, z up (the map's world frame)".to_string(),
        Up::Y => "comment up y: written (x, y, z) = world (x, z, -y), rotated -90 degrees about x"
            .to_string(),
    };
    let mut head = format!(
        "ply\nformat binary_little_endian 1.0\ncomment rogs surfels; world = local + origin {} {} {}\n{axes}\ncomment world frame: {}\nelement vertex {}\n",
        origin[0], origin[1], origin[2], frame.replace('\n', " "), count
    );
    for name in PROPS {
        head.push_str(&format!("property float {name}\n"));
    }
    head.push_str("end_header\n");
    head
}

/// Appends one row per surfel of `p` (see `surfels_ply`).
pub fn push_rows(out: &mut Vec<u8>, p: &Params<f32>, up: Up, colours: Option<&[[u8; 3]]>) {
    for i in 0..p.len() {
        let q = p.rotation[i];
        let norm = (q.iter().map(|v| v * v).sum::<f32>()).sqrt().max(1e-12);
        let [w, x, y, z] = q.map(|v| v / norm);
        // With y up the rotation is composed with −90° about x: q' = r ⊗ q,
        // r = (√½, −√½, 0, 0).
        let [w, x, y, z] = match up {
            Up::Z => [w, x, y, z],
            Up::Y => {
                let h = std::f32::consts::FRAC_1_SQRT_2;
                [h * (w + x), h * (x - w), h * (y + z), h * (z - y)]
            }
        };
        let n = [
            2.0 * (x * z + w * y),
            2.0 * (y * z - w * x),
            1.0 - 2.0 * (x * x + y * y),
        ];
        let rgb = match colours {
            Some(c) => c[i].map(|v| (v as f32 / 255.0 - 0.5) / C0),
            None => p.rgb[i].map(|c| (c - 0.5) / C0),
        };
        let pos = turn(up, p.pos[i]);
        let row = [
            pos[0],
            pos[1],
            pos[2],
            n[0],
            n[1],
            n[2],
            rgb[0],
            rgb[1],
            rgb[2],
            p.opacity[i],
            p.log_scale[i][0],
            p.log_scale[i][1],
            FLAT_LOG_SCALE,
            w,
            x,
            y,
            z,
        ];
        for v in row {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
}
