//! Reads a projected surfel (the layout `project.wgsl` writes) from the `proj`
//! binding of the kernel that includes this file, declared there as
//! `array<vec4<f32>>`: a surfel is six aligned vec4 (PROJ_STRIDE = 24 floats), so
//! these are five vector loads and the reach test one, where scalar loads cost one
//! bounds-checked access each (lane by lane on SwiftShader).

fn load_surfel(i: u32) -> Surfel {
    let o = (PROJ_STRIDE / 4u) * i;
    let a = proj[o];
    let b = proj[o + 1u];
    let c = proj[o + 2u];
    let d = proj[o + 3u];
    let e = proj[o + 4u];
    var s: Surfel;
    s.pc = a.xyz;
    s.su = a.w;
    s.tu = b.xyz;
    s.sv = b.w;
    s.tv = c.xyz;
    s.opacity = c.w;
    s.n = d.xyz;
    s.mu = e.xy;
    return s;
}

/// The pixel rectangle outside which the surfel's alpha is below 1/255 (project.wgsl).
fn load_reach(i: u32) -> vec4<f32> {
    return proj[(PROJ_STRIDE / 4u) * i + 5u];
}
