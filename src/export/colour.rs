//! Colour maps and a tiny bitmap font for legends.

/// The viridis colour map (dark blue → green → yellow) for t in 0..1, from the
/// `colorous` crate: perceptually uniform and readable with the common forms of colour
/// blindness. The page's legends and its difference layers use the same stops.
pub fn ramp(t: f32) -> [u8; 3] {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let c = colorous::VIRIDIS.eval_continuous(t as f64);
    [c.r, c.g, c.b]
}

/// 3×5 glyphs for digits, '.', '-', ' ', 'm' and 'c' (rows top to bottom, 3 bits each).
fn glyph(c: char) -> [u8; 5] {
    match c {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '.' => [0, 0, 0, 0, 2],
        '-' => [0, 0, 7, 0, 0],
        'm' => [0, 0, 7, 7, 5],
        'c' => [0, 0, 7, 4, 7],
        _ => [0; 5],
    }
}

/// Draws `text` at (x, y) with `scale`-pixel dots into an RGB image.
pub fn draw_text(img: &mut image::RgbImage, x: u32, y: u32, text: &str, scale: u32, c: [u8; 3]) {
    for (k, ch) in text.chars().enumerate() {
        let g = glyph(ch);
        for (row, bits) in g.iter().enumerate() {
            for col in 0..3 {
                if bits & (4 >> col) == 0 {
                    continue;
                }
                for dy in 0..scale {
                    for dx in 0..scale {
                        let px = x + (k as u32 * 4 + col) * scale + dx;
                        let py = y + row as u32 * scale + dy;
                        if px < img.width() && py < img.height() {
                            img.put_pixel(px, py, image::Rgb(c));
                        }
                    }
                }
            }
        }
    }
}

/// A float layer as a colour-mapped image between `lo` and `hi`, of the map's exact
/// size (so that it overlays the other layers). NaN is black.
pub fn mapped(v: &[f32], w: u32, h: u32, lo: f32, hi: f32) -> image::RgbImage {
    let mut img = image::RgbImage::new(w, h);
    let span = (hi - lo).max(1e-6);
    for (i, &z) in v.iter().enumerate() {
        let c = if z.is_finite() {
            ramp((z - lo) / span)
        } else {
            [0, 0, 0]
        };
        img.put_pixel(i as u32 % w, i as u32 / w, image::Rgb(c));
    }
    img
}

/// The legend of a `mapped` layer, its own image: the ramp over `w` pixels and the two
/// end values (`label(lo)`, `label(hi)`) below it.
pub fn legend(w: u32, lo: f32, hi: f32, label: &dyn Fn(f32) -> String) -> image::RgbImage {
    let scale = (w / 200).clamp(1, 4);
    let mut img = image::RgbImage::new(w, 12 * scale);
    for x in 0..w {
        let c = ramp(x as f32 / (w.max(2) - 1) as f32);
        for y in 0..4 * scale {
            img.put_pixel(x, y, image::Rgb(c));
        }
    }
    let white = [255, 255, 255];
    draw_text(&mut img, 1, 5 * scale, &label(lo), scale, white);
    let right = label(hi);
    let tw = right.chars().count() as u32 * 4 * scale;
    draw_text(
        &mut img,
        w.saturating_sub(tw + 1),
        5 * scale,
        &right,
        scale,
        white,
    );
    img
}
