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
