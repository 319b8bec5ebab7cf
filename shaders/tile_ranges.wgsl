//! tile_ranges: after sorting, each tile's pairs are contiguous; one invocation per
//! pair marks where its tile starts and ends (ranges cleared to 0 beforehand, so
//! tiles without surfels stay empty). The pair count comes from the GPU (`total`).

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> keys: array<u32>;
@group(0) @binding(2) var<storage, read> total: array<u32>;
@group(0) @binding(3) var<storage, read_write> ranges: array<u32>;
@group(0) @binding(4) var<uniform> grid: vec4<u32>; // row stride, capacity

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = gid.x + gid.y * grid.x;
    let n = min(total[0], grid.y);
    if k >= n {
        return;
    }
    let shift = 32u - view.tile_bits;
    let tile = keys[k] >> shift;
    if k == 0u || (keys[k - 1u] >> shift) != tile {
        ranges[2u * tile] = k;
    }
    if k == n - 1u || (keys[k + 1u] >> shift) != tile {
        ranges[2u * tile + 1u] = k + 1u;
    }
}
