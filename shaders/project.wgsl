//! project: per surfel, cull to the box in front of the camera, transform centre,
//! tangent axes and normal to camera space, project the centre, and bound the ±3σ
//! footprint (and the ±2 px low-pass floor) in tiles, keeping of that box the tiles
//! the projected parallelogram itself touches (`footprint_mask`). Also bounds, in pixels, where the
//! surfel can reach alpha ≥ 1/255 at all (±3.5σ and ±2.5 px, see `reach_rect`), so that
//! the compositing kernels skip far pixels of a tile with four compares instead of a
//! ray–plane evaluation: a pure speed-up that changes no output. Writes the projected surfel and
//! its tile count (0 when culled). One invocation per candidate (the surfels the host
//! found may be in the box, src/render/candidates.rs), writing at its slot; 256 per
//! workgroup (the browser maximum), 2D grid for more than 65535 workgroups.
//!
//! Oracle: src/render/project.rs.

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> pos: array<f32>;
@group(0) @binding(2) var<storage, read> rotation: array<f32>;
@group(0) @binding(3) var<storage, read> log_scale: array<f32>;
@group(0) @binding(4) var<storage, read> opacity: array<f32>;
@group(0) @binding(5) var<storage, read_write> proj: array<f32>;
@group(0) @binding(6) var<storage, read_write> tile_count: array<u32>;
@group(0) @binding(7) var<uniform> grid: vec4<u32>;
// Slot → surfel.
@group(0) @binding(8) var<storage, read> cand: array<u32>;

fn to_cam(p: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(view.w2c0.xyz, p) + view.w2c0.w, dot(view.w2c1.xyz, p) + view.w2c1.w, dot(view.w2c2.xyz, p) + view.w2c2.w);
}

fn rot_to_cam(v: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(view.w2c0.xyz, v), dot(view.w2c1.xyz, v), dot(view.w2c2.xyz, v));
}

/// Pixel rectangle (x0, y0, x1, y1) outside which alpha < 1/255 for any opacity:
/// alpha ≥ 1/255 needs ρ ≤ 2 ln 255 ≈ 11.1, i.e. the low-pass distance ≤ 2.36 px or the
/// ray hitting the plane within 3.33σ, whose projection lies in the hull of the ±3.5σ
/// corners while they are in front of the camera (else the whole screen).
fn reach_rect(pc: vec3<f32>, tu: vec3<f32>, tv: vec3<f32>, su: f32, sv: f32, mu: vec2<f32>) -> vec4<f32> {
    var lo = mu - vec2<f32>(2.5);
    var hi = mu + vec2<f32>(2.5);
    for (var c = 0u; c < 4u; c++) {
        let a = select(-3.5, 3.5, (c & 1u) != 0u);
        let b = select(-3.5, 3.5, (c & 2u) != 0u);
        let corner = pc + a * su * tu + b * sv * tv;
        if corner.z < 0.1 * view.near {
            return vec4<f32>(-BIG, -BIG, BIG, BIG);
        }
        let uv = vec2<f32>(view.fx * corner.x / corner.z + view.cx, view.fy * corner.y / corner.z + view.cy);
        lo = min(lo, uv);
        hi = max(hi, uv);
    }
    return vec4<f32>(lo, hi);
}

/// Which tiles of the box t = [x0, y0, x1, y1) the footprint touches, bit j for the
/// box's j-th tile in row-major order: the projected ±3σ parallelogram `q` or the
/// ±2 px square around `mu`; a tile is dropped when all four of its corners lie
/// strictly outside one edge of the parallelogram. Boxes of more than MASK_TILES
/// tiles, and a parallelogram reaching behind the camera (`whole`), keep them all.
/// Exactly `footprint_mask` in src/render/project.rs.
fn footprint_mask(t: vec4<u32>, q: array<vec2<f32>, 4>, mu: vec2<f32>, whole: bool) -> u32 {
    let n = (t.z - t.x) * (t.w - t.y);
    if whole || n > MASK_TILES {
        return 0xffffffffu;
    }
    let e1 = q[1] - q[0];
    let e2 = q[2] - q[0];
    let e3 = q[3] - q[0];
    let area = (e1.x * e2.y - e1.y * e2.x) + (e2.x * e3.y - e2.y * e3.x);
    let sgn = select(-1.0, 1.0, area >= 0.0);
    let size = f32(TILE);
    var mask = 0u;
    var j = 0u;
    for (var ty = t.y; ty < t.w; ty++) {
        for (var tx = t.x; tx < t.z; tx++) {
            let lo = vec2<f32>(f32(tx) * size, f32(ty) * size);
            let hi = lo + vec2<f32>(size);
            let square = mu.x + 2.0 >= lo.x && mu.x - 2.0 <= hi.x && mu.y + 2.0 >= lo.y && mu.y - 2.0 <= hi.y;
            var separated = false;
            for (var e = 0u; e < 4u; e++) {
                let p = q[e];
                let d = q[(e + 1u) % 4u] - p;
                let nrm = vec2<f32>(-d.y * sgn, d.x * sgn);
                let m = max(max(dot(nrm, lo - p), dot(nrm, vec2<f32>(hi.x, lo.y) - p)), max(dot(nrm, vec2<f32>(lo.x, hi.y) - p), dot(nrm, hi - p)));
                separated = separated || m < 0.0;
            }
            if square || !separated {
                mask |= 1u << j;
            }
            j++;
        }
    }
    return mask;
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let slot = gid.x + gid.y * grid.x;
    if slot >= view.count {
        return;
    }
    tile_count[slot] = 0u;
    let i = cand[slot];
    let pc = to_cam(vec3<f32>(pos[3u * i], pos[3u * i + 1u], pos[3u * i + 2u]));
    if pc.z < view.near || pc.z > view.far || abs(pc.x) > view.half_width {
        return;
    }
    let q4 = vec4<f32>(rotation[4u * i], rotation[4u * i + 1u], rotation[4u * i + 2u], rotation[4u * i + 3u]);
    let qn = q4 / sqrt(dot(q4, q4));
    let w = qn.x;
    let x = qn.y;
    let y = qn.z;
    let z = qn.w;
    let tu = rot_to_cam(vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)));
    let tv = rot_to_cam(vec3<f32>(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)));
    let n = rot_to_cam(vec3<f32>(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)));
    let su = exp(log_scale[2u * i]);
    let sv = exp(log_scale[2u * i + 1u]);
    let mu = vec2<f32>(view.fx * pc.x / pc.z + view.cx, view.fy * pc.y / pc.z + view.cy);
    var lo = mu - vec2<f32>(2.0);
    var hi = mu + vec2<f32>(2.0);
    // The corners in order around the parallelogram: (-,-), (+,-), (+,+), (-,+).
    var q: array<vec2<f32>, 4>;
    var whole = false;
    for (var c = 0u; c < 4u; c++) {
        let a = select(-1.0, 1.0, c == 1u || c == 2u);
        let b = select(-1.0, 1.0, c >= 2u);
        let corner = pc + a * EXTENT_SIGMA * su * tu + b * EXTENT_SIGMA * sv * tv;
        whole = whole || corner.z < 0.1 * view.near;
        let cz = max(corner.z, 0.1 * view.near);
        let uv = vec2<f32>(view.fx * corner.x / cz + view.cx, view.fy * corner.y / cz + view.cy);
        q[c] = uv;
        lo = min(lo, uv);
        hi = max(hi, uv);
    }
    let reach = reach_rect(pc, tu, tv, su, sv, mu);
    let wh = vec2<f32>(f32(view.width), f32(view.height));
    if hi.x < 0.0 || hi.y < 0.0 || lo.x >= wh.x || lo.y >= wh.y {
        return;
    }
    let t = f32(TILE);
    let tx0 = u32(clamp(floor(lo.x / t), 0.0, f32(view.tiles_x)));
    let ty0 = u32(clamp(floor(lo.y / t), 0.0, f32(view.tiles_y)));
    let tx1 = u32(clamp(floor(hi.x / t), 0.0, f32(view.tiles_x - 1u))) + 1u;
    let ty1 = u32(clamp(floor(hi.y / t), 0.0, f32(view.tiles_y - 1u))) + 1u;
    let mask = footprint_mask(vec4<u32>(tx0, ty0, tx1, ty1), q, mu, whole);
    let o = PROJ_STRIDE * slot;
    proj[o] = pc.x;
    proj[o + 1u] = pc.y;
    proj[o + 2u] = pc.z;
    proj[o + 3u] = su;
    proj[o + 4u] = tu.x;
    proj[o + 5u] = tu.y;
    proj[o + 6u] = tu.z;
    proj[o + 7u] = sv;
    proj[o + 8u] = tv.x;
    proj[o + 9u] = tv.y;
    proj[o + 10u] = tv.z;
    proj[o + 11u] = 1.0 / (1.0 + exp(-opacity[i]));
    proj[o + 12u] = n.x;
    proj[o + 13u] = n.y;
    proj[o + 14u] = n.z;
    proj[o + 15u] = bitcast<f32>(mask);
    proj[o + 16u] = mu.x;
    proj[o + 17u] = mu.y;
    // Tile bounds fit 16 bits (at most 65535 tiles per axis), packed in pairs.
    proj[o + 18u] = bitcast<f32>(tx0 | (ty0 << 16u));
    proj[o + 19u] = bitcast<f32>(tx1 | (ty1 << 16u));
    // The reach rectangle last, as one aligned vec4 (`load_reach`).
    proj[o + 20u] = reach.x;
    proj[o + 21u] = reach.y;
    proj[o + 22u] = reach.z;
    proj[o + 23u] = reach.w;
    let box_tiles = (tx1 - tx0) * (ty1 - ty0);
    tile_count[slot] = select(countOneBits(mask), box_tiles, box_tiles > MASK_TILES);
}
