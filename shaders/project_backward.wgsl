//! project_backward: per surfel, camera-space view gradients (accumulated by
//! rasterize_backward) to parameter gradients: d/dposition = Wᵀ d/dpc; the rotation
//! columns' gradients Wᵀ d/dtu, Wᵀ d/dtv, Wᵀ d/dn through the quaternion (with its
//! normalisation); log-scales through exp; opacity, colour, logits pass through.
//!
//! In place: each surfel's parameter gradients (pos 3, rotation 4, log_scale 2,
//! opacity 1, rgb 3, logits C) overwrite the head of its own view-gradient slot
//! (18 + C floats), so the optimiser holds no separate gradient buffer. An invocation
//! touches only its own slot and reads every camera-space value before the slot it
//! lands on is written (slot k + 5 is read before slot k is written; logits move
//! down by 5 in increasing order), so no other invocation or ordering is involved.
//!
//! One invocation per candidate slot (src/render/candidates.rs); `cand[slot]` names
//! the surfel whose rotation and scales it reads. A candidate with no tile in this
//! view (culled or off screen) has no view gradient, and its slot is still as
//! `encode_backward` cleared it: zero, which is also its parameter gradient, so it
//! returns at once.
//!
//! Any gradient that is not `usable` (guard.wgsl), the surfel's or (invocation 0) the
//! exposure's, raises `status`, and `adam` then applies nothing.
//!
//! Oracle: src/render/project_backward.rs.

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read_write> view_grad: array<f32>;
@group(0) @binding(2) var<storage, read> rotation: array<f32>;
@group(0) @binding(3) var<storage, read> log_scale: array<f32>;
@group(0) @binding(4) var<storage, read_write> status: array<u32>;
@group(0) @binding(5) var<uniform> grid: vec4<u32>;
@group(0) @binding(6) var<storage, read> tile_count: array<u32>;
@group(0) @binding(7) var<storage, read> cand: array<u32>;

var<private> ok: bool;

/// Writes one parameter gradient and notes whether it is usable.
fn put(at: u32, g: f32) {
    view_grad[at] = g;
    ok = ok & usable(g);
}

fn wt(v: vec3<f32>) -> vec3<f32> {
    return view.w2c0.xyz * v.x + view.w2c1.xyz * v.y + view.w2c2.xyz * v.z;
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let slot = gid.x + gid.y * grid.x;
    let ch = view.channels;
    let vs = 18u + ch;
    // Before the count test: a view with no candidates still has an exposure gradient.
    if slot == 0u {
        let e = vs * view.count;
        if !(usable(view_grad[e]) & usable(view_grad[e + 1u])) {
            status[0] = 1u;
        }
    }
    if slot >= view.count {
        return;
    }
    if tile_count[slot] == 0u {
        return;
    }
    let i = cand[slot];
    let v = vs * slot;
    let dpc = vec3<f32>(view_grad[v], view_grad[v + 1u], view_grad[v + 2u]);
    let dp = wt(dpc);
    let g0 = wt(vec3<f32>(view_grad[v + 3u], view_grad[v + 4u], view_grad[v + 5u]));
    let g1 = wt(vec3<f32>(view_grad[v + 6u], view_grad[v + 7u], view_grad[v + 8u]));
    let g2 = wt(vec3<f32>(view_grad[v + 9u], view_grad[v + 10u], view_grad[v + 11u]));
    let q = vec4<f32>(rotation[4u * i], rotation[4u * i + 1u], rotation[4u * i + 2u], rotation[4u * i + 3u]);
    let norm = sqrt(dot(q, q));
    let qh = q / norm;
    let w = qh.x;
    let x = qh.y;
    let y = qh.z;
    let z = qh.w;
    let dq = 2.0 * vec4<f32>(
        dot(g0, vec3<f32>(0.0, z, -y)) + dot(g1, vec3<f32>(-z, 0.0, x)) + dot(g2, vec3<f32>(y, -x, 0.0)),
        dot(g0, vec3<f32>(0.0, y, z)) + dot(g1, vec3<f32>(y, -2.0 * x, w)) + dot(g2, vec3<f32>(z, -w, -2.0 * x)),
        dot(g0, vec3<f32>(-2.0 * y, x, -w)) + dot(g1, vec3<f32>(x, 0.0, z)) + dot(g2, vec3<f32>(w, z, -2.0 * y)),
        dot(g0, vec3<f32>(-2.0 * z, w, x)) + dot(g1, vec3<f32>(-w, -2.0 * z, y)) + dot(g2, vec3<f32>(x, y, 0.0)),
    );
    let dqn = (dq - qh * dot(qh, dq)) / norm;
    let o = v;
    ok = true;
    put(o, dp.x);
    put(o + 1u, dp.y);
    put(o + 2u, dp.z);
    put(o + 3u, dqn.x);
    put(o + 4u, dqn.y);
    put(o + 5u, dqn.z);
    put(o + 6u, dqn.w);
    put(o + 7u, view_grad[v + 12u] * exp(log_scale[2u * i]));
    put(o + 8u, view_grad[v + 13u] * exp(log_scale[2u * i + 1u]));
    put(o + 9u, view_grad[v + 14u]);
    put(o + 10u, view_grad[v + 15u]);
    put(o + 11u, view_grad[v + 16u]);
    put(o + 12u, view_grad[v + 17u]);
    for (var j = 0u; j < ch; j++) {
        put(o + 13u + j, view_grad[v + 18u + j]);
    }
    if !ok {
        status[0] = 1u;
    }
}
