//! emit: one (key, slot) pair per candidate–tile overlap (the tiles of its box that
//! `footprint_mask` kept), at the candidate's offset
//! from the prefix sum of tile counts. Pairs come out in slot order, which is surfel
//! order; the stable radix
//! sort then orders them by key = tile index in the high bits, quantised depth in the
//! low bits (computed exactly as `sort_key` in src/render/project.rs).

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> proj: array<f32>;
@group(0) @binding(2) var<storage, read> tile_count: array<u32>;
@group(0) @binding(3) var<storage, read> offsets: array<u32>;
@group(0) @binding(4) var<storage, read_write> keys: array<u32>;
@group(0) @binding(5) var<storage, read_write> values: array<u32>;
@group(0) @binding(6) var<uniform> grid: vec4<u32>; // row stride, capacity

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * grid.x;
    if i >= view.count || tile_count[i] == 0u {
        return;
    }
    let o = PROJ_STRIDE * i;
    let depth = proj[o + 2u];
    let t0 = bitcast<u32>(proj[o + 18u]);
    let t1 = bitcast<u32>(proj[o + 19u]);
    let tx0 = t0 & 0xffffu;
    let ty0 = t0 >> 16u;
    let tx1 = t1 & 0xffffu;
    let ty1 = t1 >> 16u;
    let bits = 32u - view.tile_bits;
    // tile_bits ≥ 1, so bits ≤ 31 and the shift cannot overflow.
    let top = (1u << bits) - 1u;
    let d = clamp((depth - view.near) / (view.far - view.near), 0.0, 1.0);
    let q = min(u32(d * f32(top)), top);
    // The box's tiles the footprint touches (project.wgsl, `footprint_mask`).
    let mask = bitcast<u32>(proj[o + 15u]);
    let all = (tx1 - tx0) * (ty1 - ty0) > MASK_TILES;
    var k = offsets[i];
    var j = 0u;
    for (var ty = ty0; ty < ty1; ty++) {
        for (var tx = tx0; tx < tx1; tx++) {
            if all || (mask & (1u << j)) != 0u {
                if k < grid.y {
                    keys[k] = ((ty * view.tiles_x + tx) << bits) | q;
                    values[k] = i;
                }
                k++;
            }
            j++;
        }
    }
}
