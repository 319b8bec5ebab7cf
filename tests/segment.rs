//! `rogs segment`: the engine's labels (tract) against an independent run of the same
//! model (onnxruntime in Python, installed by scripts/setup.sh) on the real KITTI
//! sample; named errors for a corrupt model and a class map that does not fit it; a
//! drive without masks labelled into a valid bundle.
#![cfg(not(target_arch = "wasm32"))]

use rogs::bundle::{Bundle, Limits};
use rogs::segment::{label_bundle, ClassMap, SegmentError, Segmenter};
use std::path::{Path, PathBuf};

fn shared(rel: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared")
        .join(rel);
    assert!(
        p.exists(),
        "{} is missing (the shared folder beside the repository, as in CI)",
        p.display()
    );
    p
}

fn model() -> (String, Vec<u8>) {
    let p = shared("models/twinlitenet/twinlitenet.onnx");
    (p.display().to_string(), std::fs::read(&p).expect("model"))
}

#[test]
fn labels_agree_with_onnxruntime_on_real_frames() {
    let (name, bytes) = model();
    let seg = Segmenter::new(&name, &bytes, ClassMap::twinlitenet()).expect("model loads");
    let python = Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/segment/ort_classes.py");
    let dir = std::env::temp_dir().join(format!("rogs-segment-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("tmp");
    let mut road = 0usize;
    for frame in [0, 25, 50] {
        let img = shared(&format!(
            "data/kitti-odometry-sample/sequences/00/image_0/{frame:06}.png"
        ));
        // The KITTI frames are grey: widened to RGB, as the bundle reader does.
        let rgb = image::open(&img).expect("frame").to_rgb8();
        let input = seg.input(&rgb);
        let (inp, out) = (dir.join("in.f32"), dir.join("out.u8"));
        let raw: Vec<u8> = input.iter().flat_map(|v| v.to_le_bytes()).collect();
        std::fs::write(&inp, raw).expect("write input");
        let status = std::process::Command::new(&python)
            .args([
                script.as_os_str(),
                name.as_ref(),
                inp.as_os_str(),
                out.as_os_str(),
            ])
            .status()
            .unwrap_or_else(|e| panic!("{}: {e} (scripts/setup.sh installs it)", python.display()));
        assert!(status.success(), "onnxruntime run failed");
        let theirs = std::fs::read(&out).expect("onnxruntime classes");
        let ours = seg.classes_of_input(input).expect("tract run");
        assert_eq!(ours.len(), theirs.len());
        let same = ours.iter().zip(&theirs).filter(|(a, b)| a == b).count();
        let agree = same as f64 / ours.len() as f64;
        eprintln!("frame {frame}: {:.4} of pixels agree", agree);
        assert!(agree >= 0.99, "frame {frame}: agreement {agree}");
        road += ours.iter().filter(|&&c| c == 1).count();
        // The label at the image's size.
        let l = seg.label(&rgb).expect("label");
        assert_eq!(l.dimensions(), rgb.dimensions());
    }
    assert!(
        road > 1000,
        "the model should find road in a KITTI street ({road} px)"
    );
}

#[test]
fn a_corrupt_model_and_a_class_map_that_does_not_fit_are_named() {
    let e = Segmenter::new("bad.onnx", b"not a model", ClassMap::twinlitenet())
        .err()
        .expect("refused");
    assert!(matches!(e, SegmentError::Model { .. }), "{e}");
    assert!(
        e.to_string().starts_with("bad.onnx: not an ONNX model"),
        "{e}"
    );
    let (name, bytes) = model();
    let mut map = ClassMap::twinlitenet();
    map.outputs[0].output = "lane_lines".into();
    let e = Segmenter::new(&name, &bytes, map).err().expect("refused");
    let msg = e.to_string();
    assert!(
        msg.contains("\"lane_lines\"") && msg.contains("drivable_area, lanes"),
        "{msg}"
    );
    let mut map = ClassMap::twinlitenet();
    map.outputs[1].channel = 5;
    let seg = Segmenter::new(&name, &bytes, map).expect("loads");
    let e = seg
        .classes_of_input(vec![0.5; 3 * 320 * 320])
        .expect_err("refused");
    assert!(
        matches!(
            e,
            SegmentError::Channel {
                channels: 2,
                channel: 5,
                ..
            }
        ),
        "{e}"
    );
    // A class map in JSON naming a class it does not define.
    let json = br#"{"input": {"width": 320, "height": 320},
        "classes": [{"id": 1, "name": "road", "color": [1, 2, 3], "role": "road"}],
        "outputs": [{"output": "lanes", "channel": 1, "class": 7}], "default": 1}"#;
    let e = ClassMap::from_json("map.json", json).expect_err("refused");
    assert!(e.contains("outputs[0].class 7"), "{e}");
    let e = ClassMap::from_json("map.json", b"{\"input\": 3}").expect_err("refused");
    assert!(e.starts_with("map.json: ") && e.contains("input"), "{e}");
}

#[test]
fn a_drive_without_masks_becomes_a_labelled_bundle() {
    let cfg = rogs::synth::SynthConfig {
        labels: false,
        ..rogs::synth::SynthConfig::preset(rogs::synth::Preset::Tiny, 3)
    };
    let out = rogs::synth::generate(&cfg, &|_, _, _| {}).expect("synth");
    let zip = rogs::bundle::write_zip(&out.manifest, &out.files).expect("zip");
    let b = Bundle::from_zip_bytes(zip, Limits::default()).expect("valid");
    assert!(!b.manifest.labelled());
    let (name, bytes) = model();
    let seg = Segmenter::new(&name, &bytes, ClassMap::twinlitenet()).expect("model");
    let mut seen = Vec::new();
    let done = label_bundle(&b, &seg, std::io::Cursor::new(Vec::new()), &mut |d, t| {
        seen.push((d, t))
    })
    .expect("labelled");
    let views = b.manifest.frames.len();
    assert_eq!(seen.last(), Some(&(views, views)));
    // Its truth names other classes: left out, and said.
    assert!(done.notes.iter().any(|n| n.contains("ground truth")));
    let l = Bundle::from_zip_bytes(done.sink.into_inner(), Limits::default())
        .expect("the labelled bundle is valid");
    assert!(l.manifest.labelled());
    assert_eq!(l.manifest.semantic_classes, ClassMap::twinlitenet().classes);
    let label = l.read_view_label(0, 0).expect("label");
    assert_eq!(label.dimensions(), (cfg.width, cfg.height));
}
