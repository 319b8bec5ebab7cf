//! Reads a projected surfel (the layout `project.wgsl` writes) from the `proj`
//! binding of the kernel that includes this file.

fn load_surfel(i: u32) -> Surfel {
    let o = PROJ_STRIDE * i;
    var s: Surfel;
    s.pc = vec3<f32>(proj[o], proj[o + 1u], proj[o + 2u]);
    s.su = proj[o + 3u];
    s.tu = vec3<f32>(proj[o + 4u], proj[o + 5u], proj[o + 6u]);
    s.sv = proj[o + 7u];
    s.tv = vec3<f32>(proj[o + 8u], proj[o + 9u], proj[o + 10u]);
    s.opacity = proj[o + 11u];
    s.n = vec3<f32>(proj[o + 12u], proj[o + 13u], proj[o + 14u]);
    s.mu = vec2<f32>(proj[o + 16u], proj[o + 17u]);
    return s;
}

/// The pixel rectangle outside which the surfel's alpha is below 1/255 (project.wgsl).
fn load_reach(i: u32) -> vec4<f32> {
    let o = PROJ_STRIDE * i;
    return vec4<f32>(proj[o + 15u], proj[o + 20u], proj[o + 21u], proj[o + 22u]);
}
