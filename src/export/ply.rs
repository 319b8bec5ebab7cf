//! The surfel model as a binary PLY in the layout of 3D Gaussian splatting files
//! (x y z, normals, f_dc_0..2, opacity, scale_0..2 as logs, rot_0..3 as w x y z), so
//! that common splat viewers open it. Surfels are flat: scale_2 is a tiny constant.

use crate::render::Params;

/// SH degree-0 constant: colour = 0.5 + C0 · f_dc.
const C0: f32 = 0.282_094_8;
/// log of the normal-axis scale written for flat surfels (0.1 mm).
const FLAT_LOG_SCALE: f32 = -9.21;

/// PLY bytes of `p`; positions are local (world − `origin`), recorded in a comment.
pub fn surfels_ply(p: &Params<f32>, origin: [f64; 3]) -> Vec<u8> {
    let props = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0",
        "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
    ];
    let mut head = format!(
        "ply\nformat binary_little_endian 1.0\ncomment rogs surfels; world = local + origin {} {} {}\nelement vertex {}\n",
        origin[0], origin[1], origin[2], p.len()
    );
    for name in props {
        head.push_str(&format!("property float {name}\n"));
    }
    head.push_str("end_header\n");
    let mut out = head.into_bytes();
    out.reserve(p.len() * props.len() * 4);
    for i in 0..p.len() {
        let q = p.rotation[i];
        let norm = (q.iter().map(|v| v * v).sum::<f32>()).sqrt().max(1e-12);
        let [w, x, y, z] = q.map(|v| v / norm);
        let n = [
            2.0 * (x * z + w * y),
            2.0 * (y * z - w * x),
            1.0 - 2.0 * (x * x + y * y),
        ];
        let rgb = p.rgb[i].map(|c| (c - 0.5) / C0);
        let row = [
            p.pos[i][0],
            p.pos[i][1],
            p.pos[i][2],
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
    out
}
