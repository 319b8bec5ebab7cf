//! Writes the bundles the page tests drop on the page: `valid.zip` (the tiny example)
//! `invalid.zip` (a missing image, a broken pose and an unknown label value) and
//! `demo.zip` (a tiny synthetic scene standing in for the demo), and the map files the
//! review tests open: `truth.rogsmap` (the demo scene's truth at 5 cm: 3 × 2 tiles, 3
//! levels), `raised.rogsmap` (the same with every elevation 3 cm higher, as map B),
//! `big.rogsmap` (1.7 km of highway at 10 cm: 17 000 px, wider than a texture may
//! be), `bad-format.rogsmap` and `truncated.rogsmap` (damaged), and `points.json`
//! (world points on the road with their level-0 elevation, read natively), and
//! `splats-z.ply`, `splats-y.ply`, `splats-semantic.ply` with `splats.json` (the
//! surfels they hold, for a real splat reader to be checked against), and the catalogue
//! of malformed bundles in `catalogue/` (`rogs example --malformed`), and for the
//! page's segmentation: `kitti-unlabelled.zip` (frames of the real KITTI sample, no
//! labels), `kitti-labelled-native.zip` (the same labelled natively by `rogs
//! segment`'s code), the model `twinlitenet.onnx` and a damaged `corrupt.onnx`.
//! Usage: `cargo run --example page_fixtures -- OUT_DIR`.

use rogs::bundle::example::{self, png_gray};
use rogs::bundle::write_zip;

fn main() -> Result<(), String> {
    let out = std::path::PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "target/page-fixtures".into()),
    );
    std::fs::create_dir_all(&out).map_err(|e| e.to_string())?;
    let (m, files) = example::tiny();
    std::fs::write(out.join("valid.zip"), write_zip(&m, &files)?).map_err(|e| e.to_string())?;

    let (mut m, mut files) = example::tiny();
    files.retain(|(p, _)| p != "images/front/000001.png");
    m.frames[2].vehicle_to_world[0][0] = 2.0;
    let mut lab = image::GrayImage::new(example::WIDTH, example::HEIGHT);
    lab.put_pixel(3, 4, image::Luma([99]));
    if let Some(f) = files
        .iter_mut()
        .find(|(p, _)| p == "labels/front/000000.png")
    {
        f.1 = png_gray(&lab);
    }
    std::fs::write(out.join("invalid.zip"), write_zip(&m, &files)?).map_err(|e| e.to_string())?;
    // Stands in for the demo scene `npm start` generates (the tiny preset, for speed).
    let cfg = rogs::synth::SynthConfig::preset(rogs::synth::Preset::Tiny, 1);
    let demo = rogs::synth::generate(&cfg, &|_, _, _| {})?;
    std::fs::write(
        out.join("demo.zip"),
        write_zip(&demo.manifest, &demo.files)?,
    )
    .map_err(|e| e.to_string())?;
    // A drive without masks: the same tiny scene with its labels left out.
    let cfg = rogs::synth::SynthConfig {
        labels: false,
        ..rogs::synth::SynthConfig::preset(rogs::synth::Preset::Tiny, 1)
    };
    let bare = rogs::synth::generate(&cfg, &|_, _, _| {})?;
    std::fs::write(
        out.join("unlabelled.zip"),
        write_zip(&bare.manifest, &bare.files)?,
    )
    .map_err(|e| e.to_string())?;
    maps(&out)?;
    splats(&out)?;
    #[cfg(not(target_arch = "wasm32"))]
    segmentation(&out)?;
    rogs::bundle::catalogue::write(&out.join("catalogue"))?;
    eprintln!(
        "wrote {}/valid.zip, invalid.zip, demo.zip, unlabelled.zip and the map files",
        out.display()
    );
    Ok(())
}

/// The page's segmentation fixtures: 4 frames of the real KITTI sample without
/// labels, the same labelled natively (the page's labels are checked against them),
/// TwinLiteNet (shared/models) and a damaged copy of it. Native only (the importer
/// and the runtime are).
#[cfg(not(target_arch = "wasm32"))]
fn segmentation(out: &std::path::Path) -> Result<(), String> {
    let shared = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
    let root = shared.join("data/kitti-odometry-sample");
    let mut o =
        rogs::import::kitti::KittiOptions::new(&root, "00", out.join("kitti-unlabelled.zip"));
    o.frames = Some(0..4);
    rogs::import::kitti::import(&o, &mut |_, _, _| {}).map_err(|e| e.to_string())?;
    let model = std::fs::read(shared.join("models/twinlitenet/twinlitenet.onnx"))
        .map_err(|e| format!("the test model (shared/models/twinlitenet): {e}"))?;
    let zip = std::fs::read(out.join("kitti-unlabelled.zip")).map_err(|e| e.to_string())?;
    let b = rogs::bundle::Bundle::from_zip_bytes(zip, rogs::bundle::Limits::default())
        .map_err(|e| e.to_string())?;
    let seg = rogs::segment::Segmenter::new(
        "twinlitenet.onnx",
        &model,
        rogs::segment::ClassMap::twinlitenet(),
    )
    .map_err(|e| e.to_string())?;
    let done =
        rogs::segment::label_bundle(&b, &seg, std::io::Cursor::new(Vec::new()), &mut |_, _| {})?;
    let write = |name: &str, bytes: &[u8]| {
        std::fs::write(out.join(name), bytes).map_err(|e| format!("{name}: {e}"))
    };
    write("kitti-labelled-native.zip", &done.sink.into_inner())?;
    write("twinlitenet.onnx", &model)?;
    write("corrupt.onnx", &model[..model.len() / 2])
}

fn entries(zip: &[u8]) -> Result<Vec<(String, Vec<u8>)>, String> {
    let mut a = zip::ZipArchive::new(std::io::Cursor::new(zip)).map_err(|e| e.to_string())?;
    (0..a.len())
        .map(|i| {
            let mut f = a.by_index(i).map_err(|e| e.to_string())?;
            let mut v = Vec::new();
            std::io::Read::read_to_end(&mut f, &mut v).map_err(|e| e.to_string())?;
            let name = f.name().map(|n| n.to_string()).unwrap_or_default();
            Ok((name, v))
        })
        .collect()
}

fn rezip(files: &[(String, Vec<u8>)]) -> Result<Vec<u8>, String> {
    let mut z = rogs::bundle::ZipBundleWriter::new(std::io::Cursor::new(Vec::new()));
    for (n, b) in files {
        z.add(n, b)?;
    }
    Ok(z.finish_raw()?.into_inner())
}

fn f32s(b: &[u8]) -> Vec<f32> {
    b.chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

fn maps(out: &std::path::Path) -> Result<(), String> {
    use rogs::export::map_file::MapIndex;
    use rogs::synth::{truth, world_and_poses, Preset, SynthConfig};
    let write = |name: &str, bytes: &[u8]| {
        std::fs::write(out.join(name), bytes).map_err(|e| format!("{name}: {e}"))
    };
    let cfg = SynthConfig::preset(Preset::Demo, 1);
    let (world, poses) = world_and_poses(&cfg, &|_, _, _| {});
    let map = truth::map_file(&world, &poses, "demo truth", 6.0, 0.05, &mut |_, _| {})?;
    write("truth.rogsmap", &map)?;
    let files = entries(&map)?;
    let raised: Vec<(String, Vec<u8>)> = files
        .iter()
        .map(|(n, b)| {
            if n.starts_with("values/elevation/") {
                let v: Vec<u8> = f32s(b)
                    .iter()
                    .flat_map(|z| (z + 0.03).to_le_bytes())
                    .collect();
                (n.clone(), v)
            } else if n == "map.json" {
                let t = String::from_utf8_lossy(b)
                    .replace("\"demo truth\"", "\"demo truth, 3 cm higher\"");
                (n.clone(), t.into_bytes())
            } else {
                (n.clone(), b.clone())
            }
        })
        .collect();
    write("raised.rogsmap", &rezip(&raised)?)?;
    // Points on the road with their elevation from the level-0 tiles, for the profile.
    let index: MapIndex = serde_json::from_slice(
        &files
            .iter()
            .find(|f| f.0 == "map.json")
            .ok_or("map.json")?
            .1,
    )
    .map_err(|e| e.to_string())?;
    let mut points = Vec::new();
    for &(x, y) in &[(22.0, -1.0), (28.0, -2.5), (33.0, 0.5)] {
        let col = ((x - index.origin[0]) / index.resolution).floor() as u32;
        let row = ((index.origin[1] - y) / index.resolution).floor() as u32;
        let (c, r) = (col / 256, row / 256);
        let (tw, _) = index.tile_size(0, c, r);
        let path = MapIndex::values_path("elevation", 0, c, r);
        let tile = f32s(&files.iter().find(|f| f.0 == path).ok_or(path.clone())?.1);
        let z = tile[((row - r * 256) * tw + (col - c * 256)) as usize];
        points.push(serde_json::json!({ "x": x, "y": y, "z": z }));
    }
    write(
        "points.json",
        serde_json::to_string(&points)
            .map_err(|e| e.to_string())?
            .as_bytes(),
    )?;
    // Damaged copies.
    let bad: Vec<(String, Vec<u8>)> = files
        .iter()
        .map(|(n, b)| {
            if n == "map.json" {
                let t = String::from_utf8_lossy(b).replace("\"rogs-map\"", "\"rogs-bundle\"");
                (n.clone(), t.into_bytes())
            } else {
                (n.clone(), b.clone())
            }
        })
        .collect();
    write("bad-format.rogsmap", &rezip(&bad)?)?;
    write("truncated.rogsmap", &map[..map.len() / 3])?;
    // Wider than any texture: 1.7 km at 10 cm.
    let mut cfg = SynthConfig::preset(Preset::Highway, 1);
    cfg.set_length_m(1700.0);
    cfg.field_cell = 0.25;
    let (world, poses) = world_and_poses(&cfg, &|_, _, _| {});
    let big = truth::map_file(
        &world,
        &poses,
        "highway truth, 1.7 km",
        6.0,
        0.1,
        &mut |_, _| {},
    )?;
    write("big.rogsmap", &big)
}

/// Six surfels with distinct positions, colours, scales, opacities, rotations and
/// classes, written as PLY with z up, with y up, and in class colours.
fn splats(out: &std::path::Path) -> Result<(), String> {
    use rogs::export::ply::{surfels_ply, Up};
    let n = 6;
    let channels = 3;
    let p = rogs::render::Params::<f32> {
        pos: (0..n)
            .map(|i| [i as f32 * 1.5 - 2.0, 0.5 * i as f32, 0.1 * i as f32 - 0.2])
            .collect(),
        rgb: (0..n)
            .map(|i| [0.1 + 0.15 * i as f32, 0.8 - 0.1 * i as f32, 0.5])
            .collect(),
        log_scale: (0..n).map(|i| [-2.0 - 0.1 * i as f32, -2.5]).collect(),
        opacity: (0..n).map(|i| -1.0 + 0.5 * i as f32).collect(),
        rotation: (0..n)
            .map(|i| {
                let a = 0.3 * i as f32;
                [(a / 2.0).cos(), 0.1, 0.05 * i as f32, (a / 2.0).sin()]
            })
            .collect(),
        logits: (0..n * channels)
            .map(|k| {
                if k % channels == (k / channels) % channels {
                    3.0
                } else {
                    0.0
                }
            })
            .collect(),
        channels,
    };
    let origin = [100.0, -50.0, 2.0];
    let colours: Vec<[u8; 3]> = (0..n)
        .map(|i| [[200, 10, 10], [10, 200, 10], [10, 10, 200]][i % 3])
        .collect();
    let write = |name: &str, bytes: &[u8]| {
        std::fs::write(out.join(name), bytes).map_err(|e| format!("{name}: {e}"))
    };
    write(
        "splats-z.ply",
        &surfels_ply(&p, origin, Up::Z, None, "test"),
    )?;
    write(
        "splats-y.ply",
        &surfels_ply(&p, origin, Up::Y, None, "test"),
    )?;
    write(
        "splats-semantic.ply",
        &surfels_ply(&p, origin, Up::Z, Some(&colours), "test"),
    )?;
    let json = serde_json::json!({
        "pos": p.pos, "rgb": p.rgb, "log_scale": p.log_scale, "opacity": p.opacity,
        "rotation": p.rotation, "class_colours": colours, "origin": origin,
    });
    write("splats.json", json.to_string().as_bytes())
}
