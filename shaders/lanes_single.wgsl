//! lanes (single): the same interface as lanes_subgroup.wgsl for adapters without
//! subgroups: every invocation walks its own list and adds its own non-zero values.

fn lanes_init(li: u32) {}

fn lanes_max(x: u32) -> u32 {
    return x;
}

fn lanes_any(b: bool) -> bool {
    return b;
}

fn lanes_add(i: u32, v: f32) {
    if v != 0.0 {
        accum_add(i, v);
    }
}
