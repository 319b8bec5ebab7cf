//! regularise: the per-surfel terms of the loss and their z gradient, written to
//! `zgrad` for every surfel (dense Adam) or for the view's candidates alone
//! (selective Adam, `rp.selective`: the surfels the step will update), and `adam` adds
//! the photometric z gradient of the surfels in the view, which `project_backward`
//! left per candidate slot:
//!   L_smooth = w_s Σ_{edges ij} (z_i − z_j)²        (grid neighbours, CSR)
//!   L_traj   = w_t Σ_i q_i ρ(z_i − ẑ_i)             (ρ: Huber with width δ)
//!   L_z      = w_z Σ_{i with LiDAR} (z_i − z_lidar,i)²
//! (sums over surfels, see `RegData::weights` for why not means)
//! The edge list is symmetric (both directions stored), so each invocation owns its
//! surfel's gradient and needs no atomics. The LiDAR elevation per surfel comes from a
//! lookup built once on the host, not a search per step. Each invocation writes its
//! three loss sums, and `partial_sums` reduces them to a triple per 256 invocations:
//! no workgroup memory and no barrier, which where a CPU runs workgroups make the
//! whole kernel dear (on lavapipe a reduction tree here took 60 % of the pass; in
//! Chromium the kernel took 10× its lavapipe time with it). An invocation handles
//! `PER` surfels (256 apart, so that neighbouring invocations read neighbouring
//! words), which keeps the written sums few. A z gradient that is not `usable`
//! (guard.wgsl) raises `status[0]`, and `adam` then applies nothing.
//!
//! Selective: invocation slot j takes candidate `cand[j]` and writes (its z
//! gradient, the surfel) to `zgrad[2j]`, `zgrad[2j + 1]`, so `adam` finds both by
//! slot; the sums cover the candidates only (each surfel's terms are its own).
//!
//! Dense: it also checks the view's candidate list (src/render/candidates.rs), which the host
//! made from positions it knew: a surfel that is not a candidate but now lies in the
//! culling box (its z moved beyond the host's margin) raises `status[1]`, and the host
//! then reads the positions back before the next view. The pass already reads every
//! surfel's position, so the check costs a few instructions per surfel.
//!
//! Oracle: src/loss/regularise.rs.

// `RegParams` (the uniform block) is generated from src/optim/train.rs and prepended.

@group(0) @binding(0) var<uniform> rp: RegParams;
@group(0) @binding(1) var<storage, read> pos: array<f32>;
@group(0) @binding(2) var<storage, read> adj_start: array<u32>;
@group(0) @binding(3) var<storage, read> adj: array<u32>;
// Per surfel: ẑ, q, LiDAR z, LiDAR weight (0 or 1).
@group(0) @binding(4) var<storage, read> priors: array<vec4<f32>>;
// Dense: z gradient per surfel (f32 bits), then `adam`'s membership words.
// Selective: (z gradient, surfel) per candidate slot.
@group(0) @binding(5) var<storage, read_write> zgrad: array<u32>;
// The invocation's (smoothness, trajectory, LiDAR) terms, summed by `partial_sums`.
@group(0) @binding(6) var<storage, read_write> partial: array<f32>;
// [0]: a gradient was not usable; [1]: a surfel in the box was not a candidate.
@group(0) @binding(7) var<storage, read_write> status: array<u32>;
@group(0) @binding(8) var<uniform> view: View;
// The view's candidates, increasing: slot → surfel.
@group(0) @binding(9) var<storage, read> cand: array<u32>;

// `PER`, the surfels per invocation, is prepended by the host (src/optim/train.rs),
// which dispatches ceil(count / (256 PER)) workgroups.

/// Surfel i's three loss terms and its z gradient.
fn terms(i: u32) -> vec4<f32> {
    var l = vec3<f32>(0.0);
    let z = pos[3u * i + 2u];
    var g = 0.0;
    for (var k = adj_start[i]; k < adj_start[i + 1u]; k++) {
        let d = z - pos[3u * adj[k] + 2u];
        // Each edge is stored twice: half its loss here, half at the other end.
        l.x += 0.5 * rp.w_smooth * d * d;
        g += 2.0 * rp.w_smooth * d;
    }
    let pr = priors[i];
    let r = z - pr.x;
    let a = abs(r);
    let rho = select(rp.huber * (a - 0.5 * rp.huber), 0.5 * r * r, a <= rp.huber);
    l.y = rp.w_traj * pr.y * rho;
    g += rp.w_traj * pr.y * clamp(r, -rp.huber, rp.huber);
    let e = z - pr.z;
    l.z = rp.w_lidar * pr.w * e * e;
    g += 2.0 * rp.w_lidar * pr.w * e;
    if !usable(g) {
        status[0] = 1u;
    }
    return vec4<f32>(l, g);
}

/// Candidate slot j (selective): its surfel's terms, (gradient, surfel) at 2j.
fn slot(j: u32) -> vec3<f32> {
    let i = cand[j];
    let t = terms(i);
    zgrad[2u * j] = bitcast<u32>(t.w);
    zgrad[2u * j + 1u] = i;
    return t.xyz;
}

/// Surfel i (dense): its terms; writes its z gradient and checks its membership.
fn surfel(i: u32) -> vec3<f32> {
    let t = terms(i);
    zgrad[i] = bitcast<u32>(t.w);
    // Membership words follow the z gradients (adam.wgsl).
    let mask = zgrad[rp.count + 2u * (i / 32u)];
    if (mask & (1u << (i % 32u))) == 0u {
        let p = vec4<f32>(pos[3u * i], pos[3u * i + 1u], pos[3u * i + 2u], 1.0);
        let depth = dot(view.w2c2, p);
        if depth >= view.near && depth <= view.far && abs(dot(view.w2c0, p)) <= view.half_width {
            status[1] = 1u;
        }
    }
    return t.xyz;
}

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let w = wg.x + wg.y * (rp.row / 256u);
    var l = vec3<f32>(0.0);
    for (var j = 0u; j < PER; j++) {
        let i = (w * PER + j) * 256u + li;
        if rp.selective != 0u {
            if i < rp.cand_count {
                l += slot(i);
            }
        } else if i < rp.count {
            l += surfel(i);
        }
    }
    // No workgroup reduction here: a barrier makes the whole kernel dear where a CPU
    // runs workgroups (partial_sums.wgsl says why).
    let at = 3u * (w * 256u + li);
    partial[at] = l.x;
    partial[at + 1u] = l.y;
    partial[at + 2u] = l.z;
}
