//! pose_grad: the rendering loss's gradient with respect to a correction of the
//! view's vehicle pose, reduced over the view's candidates to one partial sum of six
//! floats per workgroup (the host adds the partials).
//!
//! Why it needs no camera-space values: moving the camera by a rigid motion is the
//! same, for the image, as moving every surfel by the inverse motion. With the
//! correction (ω, τ) moving the vehicle to R(ω)(x − c) + c + τ (c: the frame's vehicle
//! position), a surfel at p with orientation q is seen as if it sat at
//! p − ω × (p − c) − τ with orientation exp(−ω) ⊗ q, to first order. So
//!   dL/dτ = −Σ g_p,
//!   dL/dω = −Σ [(p − c) × g_p + ½ (w g_v − g_w v + v × g_v)],
//! where g_p is the surfel's position gradient (all three axes, though only z is
//! learnt) and (g_w, g_v) its quaternion gradient with q = (w, v), both as
//! `project_backward` leaves them at the head of the candidate's view-gradient slot.
//! It runs after `project_backward` and before `adam`, and reads only.
//!
//! One invocation per candidate slot; a candidate with no tile in this view has zero
//! gradients and adds nothing. Positions are in the model's local frame, as `centre`.
//!
//! Oracle: `optim::pose::gradient`.

struct PoseParams {
    /// The frame's vehicle position (local frame), w unused.
    centre: vec4<f32>,
    /// Candidates, invocations per dispatch row, floats per view-gradient slot.
    count: u32,
    row: u32,
    stride: u32,
    pad: u32,
}

@group(0) @binding(0) var<uniform> pp: PoseParams;
@group(0) @binding(1) var<storage, read> view_grad: array<f32>;
@group(0) @binding(2) var<storage, read> pos: array<f32>;
@group(0) @binding(3) var<storage, read> rotation: array<f32>;
@group(0) @binding(4) var<storage, read> tile_count: array<u32>;
@group(0) @binding(5) var<storage, read> cand: array<u32>;
@group(0) @binding(6) var<storage, read_write> partial: array<f32>;

const WG: u32 = 256u;
var<workgroup> acc: array<f32, 1536>;

@compute @workgroup_size(256)
fn main(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let slot = gid.x + gid.y * pp.row;
    var d_omega = vec3<f32>(0.0);
    var d_tau = vec3<f32>(0.0);
    if slot < pp.count && tile_count[slot] != 0u {
        let i = cand[slot];
        let v = pp.stride * slot;
        let gp = vec3<f32>(view_grad[v], view_grad[v + 1u], view_grad[v + 2u]);
        let gw = view_grad[v + 3u];
        let gv = vec3<f32>(view_grad[v + 4u], view_grad[v + 5u], view_grad[v + 6u]);
        let p = vec3<f32>(pos[3u * i], pos[3u * i + 1u], pos[3u * i + 2u]);
        let w = rotation[4u * i];
        let qv = vec3<f32>(rotation[4u * i + 1u], rotation[4u * i + 2u], rotation[4u * i + 3u]);
        let torque = 0.5 * (w * gv - gw * qv + cross(qv, gv));
        d_omega = -(cross(p - pp.centre.xyz, gp) + torque);
        d_tau = -gp;
    }
    for (var k = 0u; k < 3u; k++) {
        acc[6u * lid + k] = d_omega[k];
        acc[6u * lid + 3u + k] = d_tau[k];
    }
    workgroupBarrier();
    for (var s = WG / 2u; s > 0u; s = s / 2u) {
        if lid < s {
            for (var k = 0u; k < 6u; k++) {
                acc[6u * lid + k] += acc[6u * (lid + s) + k];
            }
        }
        workgroupBarrier();
    }
    if lid == 0u {
        let g = wid.x + wid.y * nwg.x;
        for (var k = 0u; k < 6u; k++) {
            partial[6u * g + k] = acc[k];
        }
    }
}
