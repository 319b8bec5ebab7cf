//! lanes (subgroup): gradient adds reduced across the subgroup first, then one atomic
//! per value by the subgroup's first lane. `rasterize_backward` walks its tile's list
//! in lockstep within a subgroup (the loop bound is `lanes_max` of the pixels' own
//! bounds, and it skips a surfel only when `lanes_any` says no lane uses it), so every
//! lane reaches every `lanes_add` with the same address, adding zero when none of its
//! pixels uses the surfel. Neighbouring pixels share most surfels: on lavapipe
//! (8 lanes of four pixels each) this turns up to 32 pixels' adds into one atomic. The uniformity diagnostic is off
//! because the analysis is workgroup-wide and cannot see that these branches are
//! uniform within the subgroup, which is all that the subgroup built-ins need.

diagnostic(off, subgroup_uniformity);

var<private> lane_leader: bool;

/// Call once at the start of the kernel, with every invocation active.
fn lanes_init(li: u32) {
    lane_leader = subgroupBroadcastFirst(li) == li;
}

fn lanes_max(x: u32) -> u32 {
    return subgroupMax(x);
}

fn lanes_any(b: bool) -> bool {
    return subgroupAny(b);
}

fn lanes_add(i: u32, v: f32) {
    let s = subgroupAdd(v);
    if lane_leader && s != 0.0 {
        accum_add(i, s);
    }
}
