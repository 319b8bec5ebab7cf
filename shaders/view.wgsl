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
    pad1: u32,
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

/// Whether pixel (px, py) lies outside a surfel's reach rectangle (x0, y0, x1, y1).
fn out_of_reach(r: vec4<f32>, px: f32, py: f32) -> bool {
    return px < r.x || py < r.y || px > r.z || py > r.w;
}

/// Whether the column of pixels at x from rows y0 to y1 (pixel centres) lies wholly
/// outside a reach rectangle: `out_of_reach` for each of them, in one test.
fn out_of_column(r: vec4<f32>, px: f32, y0: f32, y1: f32) -> bool {
    return px < r.x || px > r.z || y1 < r.y || y0 > r.w;
}

/// One surfel evaluated at one pixel (see src/render/rasterize.rs, `Eval`).
struct Eval {
    d: vec3<f32>,
    lambda: f32,
    q: vec3<f32>,
    u: f32,
    v: f32,
    delta: vec2<f32>,
    ray_hit: bool,
    g: f32,
    raw_alpha: f32,
    alpha: f32,
}

fn eval_surfel(s: Surfel, px: f32, py: f32, view: View) -> Eval {
    var e: Eval;
    e.d = vec3<f32>((px - view.cx) / view.fx, (py - view.cy) / view.fy, 1.0);
    let nd = dot(s.n, e.d);
    let np = dot(s.n, s.pc);
    e.lambda = 0.0;
    e.q = vec3<f32>(0.0);
    e.u = 0.0;
    e.v = 0.0;
    var rho3 = BIG;
    // Edge-on (the ray runs in the plane) or behind: no ray hit; the low-pass decides.
    if abs(nd) > 1e-6 {
        let l = np / nd;
        if l > 0.0 {
            e.lambda = l;
            e.q = e.d * l - s.pc;
            e.u = dot(e.q, s.tu) / s.su;
            e.v = dot(e.q, s.tv) / s.sv;
            rho3 = e.u * e.u + e.v * e.v;
        }
    }
    e.delta = vec2<f32>(px - s.mu.x, py - s.mu.y);
    let rho2 = LOWPASS_INV_SQ * (e.delta.x * e.delta.x + e.delta.y * e.delta.y);
    e.ray_hit = rho3 < rho2;
    let rho = select(rho2, rho3, e.ray_hit);
    e.g = exp(-0.5 * rho);
    e.raw_alpha = s.opacity * e.g;
    e.alpha = min(e.raw_alpha, MAX_ALPHA);
    return e;
}
