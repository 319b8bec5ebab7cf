//! Segmentation in the engine: a road-segmentation network (ONNX, run by tract, a
//! pure-Rust runtime) labels every view of a drive without masks, so that it becomes
//! the bundle a labelled drive would be (`rogs segment`).
//!
//! The model's input is the image resized (bilinear) to the model's size, RGB in
//! 0..1 times `scale`, less `mean`, over `std`, in NCHW. Its outputs are per-pixel
//! scores; a `ClassMap` says which output's argmax makes which bundle class: the first
//! rule whose output's argmax is its channel wins, else `default`. The class image is
//! resized back to the camera's size (nearest).
//!
//! Native only for now: the page's "compute masks with a model…" is not built.

mod classmap;

pub use classmap::{twinlitenet_classes, ClassMap, InputSpec, Rule};

use image::{GrayImage, RgbImage};
use tract_onnx::prelude::*;

/// Errors in words: which file, which output, what was expected.
#[derive(Debug, thiserror::Error)]
pub enum SegmentError {
    #[error("{path}: not an ONNX model tract can read ({reason}); expected a .onnx file such as the road-segmentation network's")]
    Model { path: String, reason: String },
    #[error("{path}: the class map's output {output:?} is not an output of the model (it has: {found}); fix \"outputs\" in the class map")]
    MissingOutput {
        path: String,
        output: String,
        found: String,
    },
    #[error("{path}: output {output:?} has {channels} channels, but the class map's rule uses channel {channel}; expected scores of shape [1, C, H, W] with C > channel")]
    Channel {
        path: String,
        output: String,
        channels: usize,
        channel: usize,
    },
    #[error("{path}: output {output:?} has shape {shape:?}; expected [1, C, {h}, {w}] per-pixel scores at the input's size")]
    Shape {
        path: String,
        output: String,
        shape: Vec<usize>,
        h: u32,
        w: u32,
    },
    #[error("{path}: running the model failed: {reason}")]
    Run { path: String, reason: String },
}

/// A loaded model and the map from its outputs to bundle classes.
pub struct Segmenter {
    path: String,
    plan: std::sync::Arc<TypedSimplePlan>,
    /// For each rule of the class map, the index of its output.
    outputs: Vec<usize>,
    map: ClassMap,
}

impl Segmenter {
    /// Loads `bytes` (named `path` in errors) with the class map `map`: every output
    /// the map names must be an output of the model.
    pub fn new(path: &str, bytes: &[u8], map: ClassMap) -> Result<Self, SegmentError> {
        let model_err = |e: TractError| SegmentError::Model {
            path: path.into(),
            reason: format!("{e:#}"),
        };
        let model = tract_onnx::onnx()
            .model_for_read(&mut &bytes[..])
            .map_err(model_err)?;
        let names: Vec<String> = model
            .output_outlets()
            .map_err(model_err)?
            .iter()
            .map(|o| {
                model
                    .outlet_label(*o)
                    .map_or_else(|| model.node(o.node).name.clone(), String::from)
            })
            .collect();
        let outputs = map
            .outputs
            .iter()
            .map(|r| {
                names.iter().position(|n| *n == r.output).ok_or_else(|| {
                    SegmentError::MissingOutput {
                        path: path.into(),
                        output: r.output.clone(),
                        found: names.join(", "),
                    }
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let (w, h) = (map.input.width as usize, map.input.height as usize);
        let plan = model
            .with_input_fact(0, f32::fact([1, 3, h, w]).into())
            .and_then(|m| m.into_optimized())
            .and_then(|m| m.into_runnable())
            .map_err(model_err)?;
        Ok(Self {
            path: path.into(),
            plan,
            outputs,
            map,
        })
    }

    /// The model's input tensor for `rgb` (NCHW, resized and normalised).
    pub fn input(&self, rgb: &RgbImage) -> Vec<f32> {
        let spec = &self.map.input;
        let (w, h) = (spec.width, spec.height);
        let small = image::imageops::resize(rgb, w, h, image::imageops::FilterType::Triangle);
        let n = (w * h) as usize;
        let mut out = vec![0.0f32; 3 * n];
        for (i, p) in small.pixels().enumerate() {
            for c in 0..3 {
                let v = p.0[c] as f32 / 255.0 * spec.scale;
                out[c * n + i] = (v - spec.mean[c]) / spec.std[c];
            }
        }
        out
    }

    /// The class of every pixel of the model's input size, from an input tensor.
    pub fn classes_of_input(&self, input: Vec<f32>) -> Result<Vec<u8>, SegmentError> {
        let spec = &self.map.input;
        let (w, h) = (spec.width as usize, spec.height as usize);
        let run_err = |e: TractError| SegmentError::Run {
            path: self.path.clone(),
            reason: format!("{e:#}"),
        };
        let t = tract_ndarray::Array4::from_shape_vec((1, 3, h, w), input).map_err(|e| {
            SegmentError::Run {
                path: self.path.clone(),
                reason: e.to_string(),
            }
        })?;
        let result = self
            .plan
            .run(tvec!(Tensor::from(t).into()))
            .map_err(run_err)?;
        let n = w * h;
        let mut class = vec![self.map.default; n];
        let mut decided = vec![false; n];
        for (rule, &k) in self.map.outputs.iter().zip(&self.outputs) {
            let out = result[k].to_plain_array_view::<f32>().map_err(run_err)?;
            let shape = out.shape().to_vec();
            if shape.len() != 4 || shape[0] != 1 || shape[2] != h || shape[3] != w {
                return Err(SegmentError::Shape {
                    path: self.path.clone(),
                    output: rule.output.clone(),
                    shape,
                    h: spec.height,
                    w: spec.width,
                });
            }
            let channels = shape[1];
            if rule.channel >= channels {
                return Err(SegmentError::Channel {
                    path: self.path.clone(),
                    output: rule.output.clone(),
                    channels,
                    channel: rule.channel,
                });
            }
            let data = out
                .as_slice()
                .map(|s| s.to_vec())
                .unwrap_or_else(|| out.iter().copied().collect());
            for i in 0..n {
                if decided[i] {
                    continue;
                }
                // Argmax over the channels; the first of equal scores wins.
                let mut best = 0;
                for c in 1..channels {
                    if data[c * n + i] > data[best * n + i] {
                        best = c;
                    }
                }
                if best == rule.channel {
                    class[i] = rule.class;
                    decided[i] = true;
                }
            }
        }
        Ok(class)
    }

    /// The label image of `rgb`: its classes resized back to its size (nearest).
    pub fn label(&self, rgb: &RgbImage) -> Result<GrayImage, SegmentError> {
        let spec = &self.map.input;
        let small = self.classes_of_input(self.input(rgb))?;
        let small = GrayImage::from_raw(spec.width, spec.height, small).unwrap_or_default();
        Ok(image::imageops::resize(
            &small,
            rgb.width(),
            rgb.height(),
            image::imageops::FilterType::Nearest,
        ))
    }

    pub fn class_map(&self) -> &ClassMap {
        &self.map
    }
}

/// Views labelled at once (decoded, run and encoded in parallel): memory stays that
/// many images whatever the drive's length.
pub const BATCH: usize = 4;

/// What `label_bundle` wrote.
pub struct Labelled<W> {
    pub manifest: crate::bundle::Manifest,
    pub sink: W,
    /// Things the user should know (the truth dropped, labels replaced).
    pub notes: Vec<String>,
}

/// Writes `b` with every view labelled by `seg` into the zip `out`: the same files,
/// a label per view (`labels/CAMERA/FRAME.png`) and the class map's class table.
/// Labels the bundle had are replaced. Its truth is kept when its classes are the
/// class map's, else dropped (its class ids would mean other classes). `progress`
/// gets (views done, views).
pub fn label_bundle<W: std::io::Write + std::io::Seek>(
    b: &crate::bundle::Bundle,
    seg: &Segmenter,
    out: W,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Labelled<W>, String> {
    let mut m = b.manifest.clone();
    let mut notes = Vec::new();
    if m.labelled() {
        notes.push("the bundle's own labels are replaced by the model's".to_string());
    }
    if m.ground_truth.is_some() && m.semantic_classes != seg.map.classes {
        notes.push(
            "its ground truth is left out: its class ids are of another class table than \
             the model's"
                .to_string(),
        );
        m.ground_truth = None;
    }
    m.semantic_classes = seg.map.classes.clone();
    let mut zip = crate::bundle::ZipBundleWriter::new(out);
    let old_labels: std::collections::HashSet<&str> = b
        .manifest
        .frames
        .iter()
        .flat_map(|f| &f.views)
        .filter_map(|v| v.label.as_deref())
        .collect();
    let mut copy: Vec<String> = m
        .referenced_files()
        .into_iter()
        .map(|(_, p)| p.to_string())
        .filter(|p| !old_labels.contains(p.as_str()))
        .collect();
    if let Some(p) = m.ground_truth.as_ref().and_then(|g| g.poses.clone()) {
        copy.push(p);
    }
    copy.sort();
    copy.dedup();
    for p in &copy {
        let bytes = b.read(p).map_err(|e| e.to_string())?;
        zip.add(p, &bytes)?;
    }
    let views: Vec<(usize, usize)> = m
        .frames
        .iter()
        .enumerate()
        .flat_map(|(f, fr)| (0..fr.views.len()).map(move |k| (f, k)))
        .collect();
    let total = views.len();
    progress(0, total);
    for (c, chunk) in views.chunks(BATCH).enumerate() {
        let labels = crate::par::par_map(chunk.len(), |i| {
            let (f, k) = chunk[i];
            let v = &m.frames[f].views[k];
            Some(
                b.read_rgb(&v.image)
                    .map_err(|e| e.to_string())
                    .and_then(|rgb| seg.label(&rgb).map_err(|e| e.to_string()))
                    .map(|l| crate::bundle::example::png_gray(&l)),
            )
        });
        for (&(f, k), png) in chunk.iter().zip(labels) {
            let v = &mut m.frames[f].views[k];
            let path = format!("labels/{}/{f:06}.png", v.camera);
            let png = png.ok_or("a view was not labelled")??;
            zip.add(&path, &png)?;
            v.label = Some(path);
        }
        progress((c * BATCH + chunk.len()).min(total), total);
    }
    let sink = zip.finish(&m)?;
    Ok(Labelled {
        manifest: m,
        sink,
        notes,
    })
}
