//! Per-view training targets: the image and its class labels packed per pixel as
//! r | g << 8 | b << 16 | channel << 24, with channel 255 outside the loss mask.
//!
//! The mask follows the official code: road pixels (classes with role `road`),
//! morphologically opened with a square (so that thin slivers of road between
//! obstacles do not count), minus the ignore classes dilated by a square (so that the
//! blurred borders of cars and people never supervise the road).

use crate::bundle::{ClassRole, Manifest};
use image::{GrayImage, RgbImage};

/// Outside the loss mask.
pub const MASKED: u32 = 255;

/// Class id → dense channel index (the logit order: the manifest's class table).
pub fn channel_of(m: &Manifest) -> [Option<u8>; 256] {
    let mut out = [None; 256];
    for (k, c) in m.classes().iter().enumerate() {
        out[c.id as usize] = Some(k as u8);
    }
    out
}

/// Box erosion (`keep_if_all`) or dilation of a binary mask with a `side`-pixel
/// square, separably (rows then columns). Borders count as outside for erosion.
fn morph(mask: &[bool], w: usize, h: usize, side: u32, erode: bool) -> Vec<bool> {
    if side <= 1 {
        return mask.to_vec();
    }
    let (lo, hi) = ((side as isize - 1) / 2, side as isize / 2);
    let pass = |src: &[bool], along_x: bool| -> Vec<bool> {
        let mut out = vec![false; src.len()];
        for y in 0..h as isize {
            for x in 0..w as isize {
                let mut acc = erode;
                for d in -lo..=hi {
                    let (xx, yy) = if along_x { (x + d, y) } else { (x, y + d) };
                    let v = xx >= 0
                        && yy >= 0
                        && (xx as usize) < w
                        && (yy as usize) < h
                        && src[yy as usize * w + xx as usize];
                    acc = if erode { acc && v } else { acc || v };
                }
                out[y as usize * w + x as usize] = acc;
            }
        }
        out
    };
    pass(&pass(mask, true), false)
}

/// The loss mask of a label image: opened road minus dilated ignore classes.
pub fn loss_mask(m: &Manifest, label: &GrayImage, open_px: u32, dilate_px: u32) -> Vec<bool> {
    let (w, h) = (label.width() as usize, label.height() as usize);
    let classes = m.classes();
    let role = |id: u8| classes.iter().find(|c| c.id == id).map(|c| c.role);
    let mut road_of = [false; 256];
    let mut ignore_of = [false; 256];
    for id in 0..=255u8 {
        road_of[id as usize] = role(id) == Some(ClassRole::Road);
        // Ids missing from the table are unknown: never supervise with them.
        ignore_of[id as usize] = role(id) != Some(ClassRole::Road);
    }
    let road: Vec<bool> = label.pixels().map(|p| road_of[p.0[0] as usize]).collect();
    let ignore: Vec<bool> = label.pixels().map(|p| ignore_of[p.0[0] as usize]).collect();
    let opened = morph(&morph(&road, w, h, open_px, true), w, h, open_px, false);
    let blocked = morph(&ignore, w, h, dilate_px, false);
    opened
        .iter()
        .zip(&blocked)
        .map(|(&r, &b)| r && !b)
        .collect()
}

/// The packed target of one view and the number of pixels inside the mask.
pub fn pack(
    m: &Manifest,
    rgb: &RgbImage,
    label: &GrayImage,
    open_px: u32,
    dilate_px: u32,
) -> (Vec<u32>, usize) {
    let mask = loss_mask(m, label, open_px, dilate_px);
    let chan = channel_of(m);
    let mut n = 0;
    let packed = rgb
        .pixels()
        .zip(label.pixels())
        .zip(&mask)
        .map(|((c, l), &inside)| {
            let ch = match (inside, chan[l.0[0] as usize]) {
                (true, Some(k)) => {
                    n += 1;
                    k as u32
                }
                _ => MASKED,
            };
            c.0[0] as u32 | (c.0[1] as u32) << 8 | (c.0[2] as u32) << 16 | ch << 24
        })
        .collect();
    (packed, n)
}
