//! Shared declarations of the rasteriser kernels: the view uniform and the layout of
//! a projected surfel (24 floats, so that one surfel is six 16-byte loads). `TILE`
//! (the tile side) and `MASK_TILES` (the largest tile box whose tiles are listed one
//! by one, `footprint_mask`) are generated from src/render and prepended.

struct View {
    w2c0: vec4<f32>,
    w2c1: vec4<f32>,
    w2c2: vec4<f32>,
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    width: u32,
    height: u32,
    tiles_x: u32,
    tiles_y: u32,
    near: f32,
    far: f32,
    half_width: f32,
    exposure_a: f32,
    exposure_b: f32,
    tile_bits: u32,
    channels: u32,
    count: u32,
    // 1: composite only the pixels inside the loss mask (training), see rasterize.
    masked: u32,
    // 1: the map's view (`Compositing::Average`): the alpha-weighted mean of the
    // surfels a pixel meets, whatever their order; see rasterize.
    average: u32,
    // The frame's log gain, added to `exposure_a`: a frame's own exposure on top of
    // its camera's, which the optimiser copies into `exposure_a` (see
    // render::gpu::forward_with). The gradient of `exposure_a` is unchanged by it.
    frame_a: f32,
    pad2: u32,
}

const PROJ_STRIDE: u32 = 24u;
/// Per-pixel forward outputs: rgb 3, depth, alpha, t_final, last, colour 3.
const PIX_STRIDE: u32 = 10u;
/// Per-pixel loss gradients: rgb 3, depth, alpha.
const GRAD_STRIDE: u32 = 5u;
const MIN_ALPHA: f32 = 0.003921569;
const MAX_ALPHA: f32 = 0.99;
const MIN_TRANSMITTANCE: f32 = 0.0001;
const LOWPASS_INV_SQ: f32 = 2.0;
const EXTENT_SIGMA: f32 = 3.0;
const BIG: f32 = 1e30;

struct Surfel {
    pc: vec3<f32>,
    su: f32,
    tu: vec3<f32>,
    sv: f32,
    tv: vec3<f32>,
    opacity: f32,
    n: vec3<f32>,
    mu: vec2<f32>,
}

/// Whether the column of pixels at x from rows y0 to y1 (pixel centres) lies wholly
/// outside a reach rectangle (x0, y0, x1, y1), in one test.
fn out_of_column(r: vec4<f32>, px: f32, y0: f32, y1: f32) -> bool {
    return px < r.x || px > r.z || y1 < r.y || y0 > r.w;
}

/// A surfel evaluated at four pixels of a column, (px, ys[j]) in lane j, where each
/// pixel's ray meets the surfel's plane (2DGS), with the screen-space low-pass floor
/// (see src/render/rasterize.rs, `Eval`). The forward pass reads `alpha` alone; the
/// rest is what the backward pass differentiates.
struct Eval4 {
    dx: f32,
    dy: vec4<f32>,
    lambda: vec4<f32>,
    qx: vec4<f32>,
    qy: vec4<f32>,
    qz: vec4<f32>,
    u: vec4<f32>,
    v: vec4<f32>,
    ddx: f32,
    ddy: vec4<f32>,
    ray_hit: vec4<bool>,
    g: vec4<f32>,
    raw_alpha: vec4<f32>,
    alpha: vec4<f32>,
}

fn eval4(s: Surfel, px: f32, ys: vec4<f32>, view: View) -> Eval4 {
    var e: Eval4;
    e.dx = (px - view.cx) / view.fx;
    e.dy = (ys - view.cy) / view.fy;
    let nd = s.n.x * e.dx + s.n.y * e.dy + s.n.z;
    let np = dot(s.n, s.pc);
    // Edge-on (the ray runs in the plane) or behind: no ray hit; the low-pass decides.
    let flat = abs(nd) > vec4<f32>(1e-6);
    let l = np / select(vec4<f32>(1.0), nd, flat);
    let hit = flat & (l > vec4<f32>(0.0));
    e.lambda = select(vec4<f32>(0.0), l, hit);
    e.qx = select(vec4<f32>(0.0), e.dx * l - s.pc.x, hit);
    e.qy = select(vec4<f32>(0.0), e.dy * l - s.pc.y, hit);
    e.qz = select(vec4<f32>(0.0), l - s.pc.z, hit);
    e.u = (e.qx * s.tu.x + e.qy * s.tu.y + e.qz * s.tu.z) / s.su;
    e.v = (e.qx * s.tv.x + e.qy * s.tv.y + e.qz * s.tv.z) / s.sv;
    let rho3 = select(vec4<f32>(BIG), e.u * e.u + e.v * e.v, hit);
    e.ddx = px - s.mu.x;
    e.ddy = ys - s.mu.y;
    let rho2 = LOWPASS_INV_SQ * (e.ddx * e.ddx + e.ddy * e.ddy);
    e.ray_hit = rho3 < rho2;
    let rho = select(rho2, rho3, e.ray_hit);
    e.g = exp(-0.5 * rho);
    e.raw_alpha = s.opacity * e.g;
    e.alpha = min(e.raw_alpha, vec4<f32>(MAX_ALPHA));
    return e;
}
