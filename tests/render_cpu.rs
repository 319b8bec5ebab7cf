//! The CPU oracle of the rasteriser against central finite differences (f64), for
//! every parameter group, and its behaviour at grazing and edge-on angles.
#![cfg(not(target_arch = "wasm32"))]

use rogs::render::project_backward;
use rogs::render::rasterize::render;
use rogs::render::rasterize_backward::{backward, OutputGrads};
use rogs::render::scene::{road_camera, road_patch};
use rogs::render::{CullConfig, Params, ViewCamera};
use rogs::synth::rng::Rng;

/// A scalar loss: fixed random weights on every output.
struct Loss {
    g: OutputGrads<f64>,
}

impl Loss {
    fn new(cam: &ViewCamera, ch: usize) -> Self {
        let mut r = Rng::new(99);
        let n = (cam.width * cam.height) as usize;
        let mut v = |k: usize| (0..k).map(|_| r.normal()).collect::<Vec<f64>>();
        Self {
            g: OutputGrads {
                rgb: v(3 * n),
                logits: v(ch * n),
                depth: v(n),
                alpha: v(n),
            },
        }
    }
    fn eval(&self, p: &Params<f64>, cam: &ViewCamera) -> f64 {
        let f = render(p, cam, &CullConfig::default());
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        dot(&f.image.rgb, &self.g.rgb)
            + dot(&f.image.logits, &self.g.logits)
            + dot(&f.image.depth, &self.g.depth)
            + dot(&f.image.alpha, &self.g.alpha)
    }
}

fn check(
    name: &str,
    analytic: f64,
    numeric: f64,
    scale: f64,
    worst: &mut f64,
    counted: &mut usize,
) {
    // Relative error where the gradient is not tiny compared with the group's largest.
    if numeric.abs().max(analytic.abs()) < 1e-3 * scale {
        return;
    }
    let rel = (analytic - numeric).abs() / numeric.abs().max(analytic.abs());
    *counted += 1;
    if rel > *worst {
        *worst = rel;
    }
    assert!(
        rel < 1e-2,
        "{name}: analytic {analytic:e} numeric {numeric:e} (rel {rel:.3e})"
    );
}

#[test]
fn cpu_backward_matches_finite_differences_for_every_parameter_group() {
    let ch = 3;
    let cam = road_camera(40, 32, 12.0);
    let p = road_patch(8, 8, 0.25, -1.0, 3.0, ch, 5);
    let loss = Loss::new(&cam, ch);
    let f = render(&p, &cam, &CullConfig::default());
    assert!(
        f.image.alpha.iter().filter(|&&a| a > 0.5).count() > 100,
        "the patch must cover the view"
    );
    let (vg, exposure) = backward(&p, &cam, &f, &loss.g);
    let g = project_backward::backward(&p, &cam, &vg);
    let h = 1e-6;
    let fd = |mutate: &dyn Fn(&mut Params<f64>, f64)| {
        let (mut a, mut b) = (p.clone(), p.clone());
        mutate(&mut a, h);
        mutate(&mut b, -h);
        (loss.eval(&a, &cam) - loss.eval(&b, &cam)) / (2.0 * h)
    };
    let mut report = Vec::new();
    type Group<'a> = (
        &'a str,
        usize,
        Box<dyn Fn(&Params<f64>, usize, usize) -> f64>,
        Box<dyn Fn(&mut Params<f64>, usize, usize, f64)>,
    );
    let groups: Vec<Group> = vec![
        (
            "z",
            1,
            Box::new(|g, i, _| g.pos[i][2]),
            Box::new(|p, i, _, d| p.pos[i][2] += d),
        ),
        // x and y are not learnt, but the pose gradient is built on them.
        (
            "xy",
            2,
            Box::new(|g, i, k| g.pos[i][k]),
            Box::new(|p, i, k, d| p.pos[i][k] += d),
        ),
        (
            "rgb",
            3,
            Box::new(|g, i, k| g.rgb[i][k]),
            Box::new(|p, i, k, d| p.rgb[i][k] += d),
        ),
        (
            "log_scale",
            2,
            Box::new(|g, i, k| g.log_scale[i][k]),
            Box::new(|p, i, k, d| p.log_scale[i][k] += d),
        ),
        (
            "opacity",
            1,
            Box::new(|g, i, _| g.opacity[i]),
            Box::new(|p, i, _, d| p.opacity[i] += d),
        ),
        (
            "rotation",
            4,
            Box::new(|g, i, k| g.rotation[i][k]),
            Box::new(|p, i, k, d| p.rotation[i][k] += d),
        ),
        (
            "logits",
            3,
            Box::new(|g, i, k| g.logits[i * 3 + k]),
            Box::new(|p, i, k, d| p.logits[i * 3 + k] += d),
        ),
    ];
    for (name, comps, get, set) in &groups {
        let all: Vec<f64> = (0..p.len())
            .flat_map(|i| (0..*comps).map(move |k| (i, k)))
            .map(|(i, k)| get(&g, i, k))
            .collect();
        let scale = all.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(scale > 0.0, "{name}: all gradients are zero");
        let (mut worst, mut counted) = (0.0, 0);
        for i in (0..p.len()).step_by(3) {
            for k in 0..*comps {
                let numeric = fd(&|q: &mut Params<f64>, d: f64| set(q, i, k, d));
                check(
                    &format!("{name}[{i}][{k}]"),
                    get(&g, i, k),
                    numeric,
                    scale,
                    &mut worst,
                    &mut counted,
                );
            }
        }
        assert!(
            counted >= 5,
            "{name}: only {counted} gradients large enough to check"
        );
        report.push(format!("{name}: {counted} checked, worst rel {worst:.1e}"));
    }
    for (k, name) in ["exposure a", "exposure b"].iter().enumerate() {
        let numeric = {
            let (mut a, mut b) = (cam, cam);
            a.exposure[k] += 1e-3;
            b.exposure[k] -= 1e-3;
            (loss.eval(&p, &a) - loss.eval(&p, &b)) / 2e-3
        };
        let (mut worst, mut counted) = (0.0, 0);
        // f32 exposure steps: a coarser h, still well inside 1e-2.
        check(
            name,
            exposure[k],
            numeric,
            exposure[k].abs(),
            &mut worst,
            &mut counted,
        );
        report.push(format!("{name}: worst rel {worst:.1e}"));
    }
    eprintln!("{}", report.join("\n"));
}

/// The world moved by the inverse of a pose correction: what the corrected camera
/// sees (rotation −ω about `centre`, translation −τ), in f64.
fn world_moved(
    p: &Params<f64>,
    c: &rogs::optim::pose::Correction,
    centre: [f64; 3],
) -> Params<f64> {
    let r = rogs::bundle::transform::exp_so3(c.omega);
    let th = (c.omega.iter().map(|v| v * v).sum::<f64>()).sqrt();
    // Quaternion of R(−ω) = exp(−ω).
    let (s, w) = ((th / 2.0).sin(), (th / 2.0).cos());
    let a = if th > 0.0 {
        c.omega.map(|v| -v / th * s)
    } else {
        [0.0; 3]
    };
    let mut out = p.clone();
    for (q, o) in p.pos.iter().zip(out.pos.iter_mut()) {
        let d = [0, 1, 2].map(|k| q[k] - centre[k] - c.tau[k]);
        // Rᵀ d + centre.
        *o = [0, 1, 2].map(|i| (0..3).map(|k| r[k][i] * d[k]).sum::<f64>() + centre[i]);
    }
    for (q, o) in p.rotation.iter().zip(out.rotation.iter_mut()) {
        let (bw, bv) = (q[0], [q[1], q[2], q[3]]);
        let cr = [
            a[1] * bv[2] - a[2] * bv[1],
            a[2] * bv[0] - a[0] * bv[2],
            a[0] * bv[1] - a[1] * bv[0],
        ];
        let dot = a[0] * bv[0] + a[1] * bv[1] + a[2] * bv[2];
        *o = [
            w * bw - dot,
            w * bv[0] + bw * a[0] + cr[0],
            w * bv[1] + bw * a[1] + cr[1],
            w * bv[2] + bw * a[2] + cr[2],
        ];
    }
    out
}

/// The pose gradient (`optim::pose::gradient`, from the surfels' gradients) against
/// central differences of the loss with the world moved by the inverse correction
/// (f64), every axis of ω and τ, about a vehicle centre away from the camera; and the
/// corrected camera (`Correction::apply`, what training renders) against that moved
/// world: the same image. (Differences of the camera itself are too coarse to check
/// against: its matrix is f32, and at steps above f32's rounding some surfel of the
/// view always crosses the edge of its tile box.)
#[test]
fn pose_gradient_matches_finite_differences_and_the_moved_camera_the_moved_world() {
    use rogs::optim::pose::{gradient, Correction};
    let ch = 3;
    let cam = road_camera(40, 32, 12.0);
    let p = road_patch(8, 8, 0.25, -1.0, 3.0, ch, 5);
    let loss = Loss::new(&cam, ch);
    let f = render(&p, &cam, &CullConfig::default());
    let (vg, _) = backward(&p, &cam, &f, &loss.g);
    let g = project_backward::backward(&p, &cam, &vg);
    // The vehicle stands off to one side of the camera and below it: rotations about
    // it also move the camera.
    let centre = [0.4, -1.5, -1.2];
    let analytic = gradient(&p, &g, centre);
    let scale = analytic.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(scale > 0.0, "the pose gradient is zero");
    let axis = |k: usize, d: f64| {
        let mut c = Correction::default();
        if k < 3 {
            c.omega[k] = d;
        } else {
            c.tau[k - 3] = d;
        }
        c
    };
    // A tilt about x of 1e-6 already takes a surfel of this patch across the edge of
    // its tile box (a jump in the loss); 1e-7 stays clear of it.
    let h = 1e-7;
    let mut report = Vec::new();
    for (k, &a) in analytic.iter().enumerate() {
        let moved = |d: f64| loss.eval(&world_moved(&p, &axis(k, d), centre), &cam);
        let numeric = (moved(h) - moved(-h)) / (2.0 * h);
        let rel = (a - numeric).abs() / numeric.abs().max(a.abs());
        report.push(format!(
            "axis {k}: analytic {:.4e} numeric {numeric:.4e} rel {rel:.1e}",
            a
        ));
        assert!(
            rel < 1e-4,
            "pose axis {k}: analytic {:e} numeric {numeric:e} (rel {rel:.3e})",
            a
        );
    }
    // A finite correction (2 cm, 5 cm, −3 cm; 0.5°, −0.3°, 1°): camera moved against
    // world moved.
    let c = Correction {
        omega: [0.5f64, -0.3, 1.0].map(f64::to_radians),
        tau: [0.02, 0.05, -0.03],
    };
    let a = render(&p, &c.apply(&cam, centre), &CullConfig::default());
    let b = render(&world_moved(&p, &c, centre), &cam, &CullConfig::default());
    let moved_px = a
        .image
        .rgb
        .iter()
        .zip(&f.image.rgb)
        .filter(|(x, y)| (*x - *y).abs() > 1e-2)
        .count();
    assert!(
        moved_px > 50,
        "the correction must change the image ({moved_px} values)"
    );
    let diff = a
        .image
        .rgb
        .iter()
        .zip(&b.image.rgb)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    report.push(format!(
        "camera moved vs world moved: max |Δrgb| {diff:.1e}"
    ));
    assert!(diff < 1e-3, "camera moved vs world moved: {diff:e}");
    eprintln!("{}", report.join("\n"));
}

#[test]
fn edge_on_and_grazing_surfels_give_finite_outputs() {
    let ch = 2;
    let cam = road_camera(32, 24, 0.0);
    let mut p = road_patch(4, 4, 0.3, -0.5, 2.0, ch, 8);
    // Surfel 0: plane containing the camera ray through the image centre (edge-on):
    // normal along camera x (world x), i.e. rotation of 90° about world y.
    let s = std::f64::consts::FRAC_1_SQRT_2;
    p.rotation[0] = [s, 0.0, s, 0.0];
    p.pos[0] = [0.0, 4.0, 1.5];
    // Surfel 1: the plane of the camera centre itself (λ would be 0).
    p.pos[1] = [0.3, 3.0, 1.5];
    p.rotation[1] = [1.0, 0.0, 0.0, 0.0];
    let f32p: Params<f32> = p.cast();
    let f = render(&f32p, &cam, &CullConfig::default());
    assert!(f
        .image
        .rgb
        .iter()
        .chain(&f.image.depth)
        .chain(&f.image.alpha)
        .chain(&f.image.logits)
        .all(|v| v.is_finite()));
    let loss = Loss::new(&cam, ch);
    let g32 = OutputGrads::<f32> {
        rgb: loss.g.rgb.iter().map(|&v| v as f32).collect(),
        logits: loss.g.logits.iter().map(|&v| v as f32).collect(),
        depth: loss.g.depth.iter().map(|&v| v as f32).collect(),
        alpha: loss.g.alpha.iter().map(|&v| v as f32).collect(),
    };
    let (vg, e) = backward(&f32p, &cam, &f, &g32);
    assert!(vg.iter().all(|v| v.is_finite()) && e.iter().all(|v| v.is_finite()));
    // The edge-on surfel is still seen, through the low-pass floor.
    assert!(f.pairs.iter().any(|&(_, i)| i == 0));
}
