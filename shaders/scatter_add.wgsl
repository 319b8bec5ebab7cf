//! scatter_add: `bins[index[i]] += values[i]` for every i.
//!
//! The smallest kernel that exercises what the rasteriser's backward pass depends on:
//! many invocations adding into the same bins through `accum_add` (prepended from
//! `accum_f32.wgsl` or `accum_cas.wgsl`, chosen from the adapter's features). Launched
//! as a 2D grid so that more than 65535 workgroups of 256 are possible; 256 is the
//! largest workgroup browsers guarantee.

struct Params {
    count: u32,
    row_stride: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(1) var<storage, read> index: array<u32>;
@group(0) @binding(2) var<storage, read> values: array<f32>;
@group(0) @binding(3) var<uniform> params: Params;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * params.row_stride;
    if i >= params.count {
        return;
    }
    accum_add(index[i], values[i]);
}
