//! The evaluation metrics of the paper, with its quirks removed: PSNR averages over
//! valid pixels only; mIoU counts only road classes present in truth or prediction;
//! elevation errors are taken at surfel centres.

use super::raster::BevRaster;
use serde::Serialize;

/// The report block shared by `rogs eval` and `rogs reconstruct`.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Metrics {
    pub psnr_db: Option<f64>,
    pub miou: Option<f64>,
    pub elevation_rmse_m: Option<f64>,
    pub elevation_mae_m: Option<f64>,
    pub elevation_p95_m: Option<f64>,
    /// Share of the truth's cells that the map covers: PSNR and mIoU are over those
    /// cells only, so a map with holes is told apart from a good one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub coverage: Option<f64>,
    /// IoU of each road class (by class id) that `miou` averages.
    #[serde(skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub iou_per_class: std::collections::BTreeMap<u8, f64>,
    /// Elevation RMSE of the initial surface at the same surfel centres, before
    /// any training (with truth).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub initial_elevation_rmse_m: Option<f64>,
    /// The elevation error's datum (a shared offset and tilt) and the error without
    /// it (against a truth raster).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub elevation_datum: Option<ElevationDatum>,
    /// The map and the exact-pose LiDAR reference over the reference's cells
    /// (`eval::vs_reference`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vs_reference: Option<VsReference>,
    /// The map against the LiDAR pseudo-ground-truth through the bundle's own poses,
    /// scored as the paper scores it and corrected (`eval::paper_protocol`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub paper_protocol: Option<PaperProtocol>,
}

/// The map against the paper's reference (accumulated LiDAR through the bundle's
/// poses, coloured and labelled from the nearest camera images, rasterised on the
/// map's own grid, as the paper renders both over the map's extent), scored two ways, so that a scene can be set beside the
/// paper's table. The two differ in PSNR only: the paper's evaluation code divides
/// the squared error summed over the cells both maps cover by every cell of the
/// raster (uncovered cells count as zero error, so the sparser the reference, the
/// higher the figure) and reads the reference's colours over 225 instead of 255;
/// `psnr_db` is the mean over the cells both cover, both colours over 255. mIoU
/// (road classes present in either, cells both cover) and elevation (each surfel
/// centre against the nearest reference point within 0.1 m in xy) are the paper's.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct PaperProtocol {
    /// Cells of the map's raster, and those the reference and the map both cover.
    pub raster_cells: usize,
    pub cells: usize,
    /// PSNR as the paper's code computes it.
    pub paper_psnr_db: Option<f64>,
    /// PSNR over the cells both cover (the corrected figure).
    pub psnr_db: Option<f64>,
    pub miou: Option<f64>,
    pub elevation_rmse_m: Option<f64>,
}

/// PSNR as the paper's evaluation computes it (`PaperProtocol`): the squared error
/// over the cells `pred` and `reference` both cover, with the reference's colours
/// read over 225, averaged over every cell of `reference`'s raster (the map's, in
/// the paper). `None` when they share no cell.
pub fn paper_psnr(pred: &BevRaster, reference: &BevRaster) -> Option<f64> {
    let mut se = 0.0;
    let mut shared = 0u64;
    for_valid_pairs(pred, reference, |p, t| {
        shared += 1;
        let (a, b) = (
            pred.rgb.get_pixel(p.0, p.1).0,
            reference.rgb.get_pixel(t.0, t.1).0,
        );
        for k in 0..3 {
            let d = a[k] as f64 / 255.0 - b[k] as f64 / 225.0;
            se += d * d;
        }
    });
    let all = 3.0 * reference.width as f64 * reference.height as f64;
    // The paper's code floors the error at 1e-10 (100 dB).
    (shared > 0).then(|| -10.0 * (se / all).max(1e-10).log10())
}

/// The map against the best map the paper's own procedure makes from the same
/// inputs with perfect poses: the LiDAR pseudo-ground-truth through the exact poses.
/// Both are scored against the truth over the same cells: those the reference and
/// the map both cover.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct VsReference {
    /// Truth cells that the reference and the map both cover: what both are scored on.
    pub cells: usize,
    /// Truth cells the reference covers (the map may cover fewer: a narrower corridor
    /// than the LiDAR reaches).
    pub reference_cells: usize,
    pub map_psnr_db: Option<f64>,
    pub map_miou: Option<f64>,
    pub ref_psnr_db: Option<f64>,
    pub ref_miou: Option<f64>,
    /// IoU of each road class (by class id) that `map_miou` and `ref_miou` average.
    pub map_iou_per_class: std::collections::BTreeMap<u8, f64>,
    pub ref_iou_per_class: std::collections::BTreeMap<u8, f64>,
}

/// PSNR (dB, peak 1.0) of `pred` against `truth` over pixels valid in both. Both
/// rasters may differ in geometry: each truth pixel looks up the prediction at its centre.
pub fn psnr(pred: &BevRaster, truth: &BevRaster) -> Option<f64> {
    Tally::of(pred, truth).psnr()
}

/// Mean IoU over `road_classes` that occur in the truth or the prediction (valid pixels).
pub fn miou(pred: &BevRaster, truth: &BevRaster, road_classes: &[u8]) -> Option<f64> {
    Tally::of(pred, truth).miou(road_classes)
}

/// IoU of each of `road_classes` that occurs in the truth or the prediction.
pub fn class_iou(pred: &BevRaster, truth: &BevRaster, road_classes: &[u8]) -> Vec<(u8, f64)> {
    Tally::of(pred, truth).class_iou(road_classes)
}

/// The sums PSNR and IoU are made of, over the pixels valid in both rasters: added
/// up over the blocks of a map too large to hold whole, they give the whole map's.
#[derive(Clone, Debug)]
pub struct Tally {
    /// Squared colour error (0–1 per channel) and the channel values counted.
    se: f64,
    n: u64,
    inter: [u64; 256],
    union: [u64; 256],
    /// Truth cells seen, and those the map covers.
    truth_cells: u64,
    covered: u64,
}

impl Default for Tally {
    fn default() -> Self {
        Self {
            se: 0.0,
            n: 0,
            inter: [0; 256],
            union: [0; 256],
            truth_cells: 0,
            covered: 0,
        }
    }
}

impl Tally {
    pub fn of(pred: &BevRaster, truth: &BevRaster) -> Self {
        let mut t = Self::default();
        t.add(pred, truth);
        t
    }

    /// Adds the pixels of `truth` valid in both (each looks up the prediction at its
    /// centre).
    pub fn add(&mut self, pred: &BevRaster, truth: &BevRaster) {
        self.truth_cells += truth.valid.pixels().filter(|v| v.0[0] != 0).count() as u64;
        for_valid_pairs(pred, truth, |p, t| {
            self.covered += 1;
            let (a, b) = (
                pred.rgb.get_pixel(p.0, p.1).0,
                truth.rgb.get_pixel(t.0, t.1).0,
            );
            for k in 0..3 {
                let d = (a[k] as f64 - b[k] as f64) / 255.0;
                self.se += d * d;
            }
            self.n += 3;
            let (a, b) = (
                pred.class_ids.get_pixel(p.0, p.1).0[0] as usize,
                truth.class_ids.get_pixel(t.0, t.1).0[0] as usize,
            );
            self.union[a] += 1;
            if a == b {
                self.inter[a] += 1;
            } else {
                self.union[b] += 1;
            }
        });
    }

    /// Share of the truth cells added that the map covers.
    pub fn coverage(&self) -> Option<f64> {
        (self.truth_cells > 0).then(|| self.covered as f64 / self.truth_cells as f64)
    }

    /// Truth cells the map covers.
    pub fn covered(&self) -> u64 {
        self.covered
    }

    pub fn psnr(&self) -> Option<f64> {
        (self.n > 0).then(|| {
            let mse = self.se / self.n as f64;
            if mse <= 0.0 {
                f64::INFINITY
            } else {
                -10.0 * mse.log10()
            }
        })
    }

    pub fn class_iou(&self, road_classes: &[u8]) -> Vec<(u8, f64)> {
        road_classes
            .iter()
            .filter(|&&c| self.union[c as usize] > 0)
            .map(|&c| {
                (
                    c,
                    self.inter[c as usize] as f64 / self.union[c as usize] as f64,
                )
            })
            .collect()
    }

    pub fn miou(&self, road_classes: &[u8]) -> Option<f64> {
        let ious = self.class_iou(road_classes);
        (!ious.is_empty()).then(|| ious.iter().map(|c| c.1).sum::<f64>() / ious.len() as f64)
    }

    /// The metrics of the pixels added, with the elevation errors `e` (taken at
    /// surfel centres, apart).
    pub fn metrics(&self, road_classes: &[u8], e: Option<ErrorStats>) -> Metrics {
        Metrics {
            psnr_db: self.psnr(),
            miou: self.miou(road_classes),
            iou_per_class: self.class_iou(road_classes).into_iter().collect(),
            elevation_rmse_m: e.map(|e| e.rmse),
            elevation_mae_m: e.map(|e| e.mae),
            elevation_p95_m: e.map(|e| e.p95),
            coverage: self.coverage(),
            elevation_datum: e.and_then(|e| e.datum),
            ..Default::default()
        }
    }
}

fn for_valid_pairs(pred: &BevRaster, truth: &BevRaster, mut f: impl FnMut((u32, u32), (u32, u32))) {
    let same = pred.origin == truth.origin
        && pred.resolution == truth.resolution
        && pred.width == truth.width
        && pred.height == truth.height;
    for r in 0..truth.height {
        for c in 0..truth.width {
            if !truth.is_valid(c, r) {
                continue;
            }
            let p = if same {
                Some((c, r))
            } else {
                let (x, y) = truth.centre(c, r);
                pred.pixel_of(x, y)
            };
            if let Some(p) = p.filter(|p| pred.is_valid(p.0, p.1)) {
                f(p, (c, r));
            }
        }
    }
}

/// Root-mean-square, mean absolute and 95th-percentile absolute error.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ErrorStats {
    pub rmse: f64,
    pub mae: f64,
    pub p95: f64,
    pub count: usize,
    /// The plane fitted to the errors, where their positions are known.
    pub datum: Option<ElevationDatum>,
}

/// The elevation error's datum: the plane `offset_m + slope_x·(x − x̄) + slope_y·(y − ȳ)`
/// (x̄, ȳ: the mean position of the surfel centres scored) fitted by least squares to
/// their errors against the truth, and `rmse_m`, the error with that plane taken out.
///
/// Why: the inputs fix the map's height only as well as the poses fix theirs. A
/// shared offset or tilt of every pose (the mean of their noise over the drive)
/// moves the sweeps and the images, and so the map, with it, and no agreement
/// between them can see it (the LiDAR alignment removes the same plane from its
/// corrections, `init::align`). With 5 cm of height noise on 26 sweeps the offset
/// alone is 0.8 cm (one standard deviation). `rmse_m` is what the map's elevation
/// holds beyond the poses' datum, as trajectories are scored after a rigid
/// alignment; `elevation_rmse_m` keeps the datum.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ElevationDatum {
    pub offset_m: f64,
    /// Metres per metre east and north.
    pub slope_x: f64,
    pub slope_y: f64,
    pub rmse_m: f64,
}

/// The datum of errors `e` at positions `xy` (`ElevationDatum`); `None` with fewer
/// than three errors or positions on one line.
pub fn elevation_datum(xy: &[[f64; 2]], e: &[f64]) -> Option<ElevationDatum> {
    let n = xy.len().min(e.len());
    if n < 3 {
        return None;
    }
    let mean = xy[..n].iter().fold([0.0; 2], |s, p| {
        [s[0] + p[0] / n as f64, s[1] + p[1] / n as f64]
    });
    let (mut m, mut rhs) = ([0.0f64; 6], [0.0f64; 3]);
    for (p, &v) in xy.iter().zip(e) {
        let g = [1.0, p[0] - mean[0], p[1] - mean[1]];
        crate::linalg::accumulate3(&mut m, &mut rhs, g, 1.0, v);
    }
    let [a, b, c] = crate::linalg::solve3(&m, &rhs, 3.0)?;
    let se: f64 = xy
        .iter()
        .zip(e)
        .map(|(p, &v)| {
            let r = v - (a + b * (p[0] - mean[0]) + c * (p[1] - mean[1]));
            r * r
        })
        .sum();
    Some(ElevationDatum {
        offset_m: a,
        slope_x: b,
        slope_y: c,
        rmse_m: (se / n as f64).sqrt(),
    })
}

pub fn error_stats(errors: &mut [f64]) -> Option<ErrorStats> {
    if errors.is_empty() {
        return None;
    }
    let n = errors.len() as f64;
    let rmse = (errors.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
    let mae = errors.iter().map(|e| e.abs()).sum::<f64>() / n;
    for e in errors.iter_mut() {
        *e = e.abs();
    }
    errors.sort_by(f64::total_cmp);
    // Nearest-rank percentile.
    let k = ((0.95 * n).ceil() as usize).clamp(1, errors.len()) - 1;
    Some(ErrorStats {
        rmse,
        mae,
        p95: errors[k],
        count: errors.len(),
        datum: None,
    })
}

/// Elevation errors of `points` (surfel centres, world xyz) against the truth raster,
/// for points over valid truth, with their datum (`ElevationDatum`).
pub fn elevation_vs_raster(points: &[[f64; 3]], truth: &BevRaster) -> Option<ErrorStats> {
    let (xy, mut errors): (Vec<[f64; 2]>, Vec<f64>) = points
        .iter()
        .filter_map(|p| {
            truth
                .elevation_xy(p[0], p[1])
                .map(|z| ([p[0], p[1]], p[2] - z))
        })
        .unzip();
    let datum = elevation_datum(&xy, &errors);
    error_stats(&mut errors).map(|s| ErrorStats { datum, ..s })
}

/// Elevation errors against reference points (accumulated LiDAR): for each point the
/// nearest reference within `radius` in xy, as in the paper (0.1 m).
pub fn elevation_vs_points(
    points: &[[f64; 3]],
    reference: &[[f64; 3]],
    radius: f64,
) -> Option<ErrorStats> {
    let grid = crate::spatial::PointGrid::new(reference, radius);
    let mut errors: Vec<f64> = points
        .iter()
        .filter_map(|p| {
            grid.nearest(p[0], p[1], radius)
                .map(|q| p[2] - reference[q][2])
        })
        .collect();
    error_stats(&mut errors)
}
