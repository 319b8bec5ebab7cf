//! Writes the bundles the page tests drop on the page: `valid.zip` (the tiny example)
//! `invalid.zip` (a missing image, a broken pose and an unknown label value) and
//! `demo.zip` (a tiny synthetic scene standing in for the demo).
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
    eprintln!(
        "wrote {}/valid.zip, invalid.zip and demo.zip",
        out.display()
    );
    Ok(())
}
