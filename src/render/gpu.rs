//! Host glue of the rasteriser kernels: buffers, pipelines and the order of passes.
//!
//! Forward, per view: the host lists the view's candidate surfels (`candidates`) →
//! `project`, and `gather` (their colours and logits into the view's `attrs`, one
//! window of the model's buffers per pass) → `scan` (tile counts to offsets, total on
//! the GPU) → `emit` (key, candidate) pairs → radix sort → `tile_ranges` →
//! `rasterize`.
//! Backward: `rasterize_backward` (camera-space gradients, accumulated with the
//! adapter's strategy) → `project_backward` (parameter gradients).
//!
//! Everything per view is indexed by candidate slot, not by surfel: projected
//! surfels, tile counts, offsets, colours and logits, pair values and view gradients.
//! `cand[slot]` is the surfel, read wherever a kernel needs the model's own parameters.
//! Only `gather` and the optimiser touch the model's logits, each one window at a
//! time, so a model's logits need not fit one storage binding.
//!
//! The pair buffers are sized from the pair count, read back once per view (4 bytes)
//! after the scan; every other count stays on the GPU.

use super::candidates::{candidates, Footprints};
use super::project::tile_bits;
use super::rasterize_backward::{OutputGrads, VIEW_GRAD};
use super::{Compositing, CullConfig, Image, Params, ViewCamera, TILE};
use crate::gpu::buffers::{
    bind, bind_ranges, dispatch, init_storage, pipeline, storage, uniform, window,
};
use crate::gpu::radix_sort::{RadixSorter, SortPairs, SortedIn};
use crate::gpu::readback::{read_bytes, read_f32};
use crate::gpu::{AccumStrategy, GpuContext, GpuError};

/// The `View` uniform and the shared rasteriser declarations.
/// shaders/view.wgsl behind the constants it shares with the oracle, generated from
/// their Rust declarations so that the two cannot disagree.
pub static VIEW_WGSL: std::sync::LazyLock<String> = std::sync::LazyLock::new(|| {
    format!(
        "const TILE: u32 = {TILE}u;\nconst MASK_TILES: u32 = {}u;\n{}",
        super::project::MASK_TILES,
        include_str!("../../shaders/view.wgsl")
    )
});
const LOAD_SURFEL_WGSL: &str = include_str!("../../shaders/load_surfel.wgsl");
/// `usable(x)`: the gradient test behind the optimiser's status word.
pub const GUARD_WGSL: &str = include_str!("../../shaders/guard.wgsl");
pub use crate::gpu::WORKGROUP_WGSL;
/// Values per block of shaders/scan.wgsl (`PER` there): one invocation's serial run.
const SCAN_PER: u32 = 8;
/// Floats per pixel of the packed forward outputs (`PIX_STRIDE` in view.wgsl).
const PIX_STRIDE: usize = 10;

/// Bytes per candidate surfel of a view's largest per-candidate buffer (the view
/// gradients, or the projected surfel): a view's candidates times this must fit the
/// adapter's binding limit.
pub fn candidate_bytes(channels: usize) -> u64 {
    4 * (24u64).max(VIEW_GRAD as u64 + channels as u64)
}

/// Bytes per pixel of a view's largest per-pixel buffer (the packed forward outputs,
/// or the logits when there are more classes): one storage binding each, so a
/// camera's pixels times this must fit the adapter's binding limit.
pub fn view_bytes_per_pixel(channels: usize) -> u64 {
    4 * PIX_STRIDE.max(channels) as u64
}

/// The rasteriser's compute pipelines.
struct RasterKernels {
    project: wgpu::ComputePipeline,
    scan_blocks: wgpu::ComputePipeline,
    scan_sums: wgpu::ComputePipeline,
    add_offsets: wgpu::ComputePipeline,
    emit: wgpu::ComputePipeline,
    gather: wgpu::ComputePipeline,
    ranges: wgpu::ComputePipeline,
    raster: wgpu::ComputePipeline,
    raster_bwd: wgpu::ComputePipeline,
    project_bwd: wgpu::ComputePipeline,
}

impl RasterKernels {
    /// The pipelines for `channels` logit channels, the backward pass's gradient
    /// adds by `strategy`, reduced over subgroups first or not.
    fn new(ctx: &GpuContext, strategy: AccumStrategy, subgroups: bool, channels: u32) -> Self {
        let ch = channels_wgsl(channels);
        let lanes = if subgroups {
            include_str!("../../shaders/lanes_subgroup.wgsl")
        } else {
            include_str!("../../shaders/lanes_single.wgsl")
        };
        let pipe = |label: &str, parts: &[&str], entry: &str| pipeline(ctx, label, parts, entry);
        let scan_per = format!("const PER: u32 = {SCAN_PER}u;");
        let scan = include_str!("../../shaders/scan.wgsl");
        Self {
            project: pipe(
                "project",
                &[&VIEW_WGSL, include_str!("../../shaders/project.wgsl")],
                "main",
            ),
            scan_blocks: pipe(
                "scan_blocks",
                &[WORKGROUP_WGSL, &scan_per, scan],
                "scan_blocks",
            ),
            scan_sums: pipe("scan_sums", &[WORKGROUP_WGSL, &scan_per, scan], "scan_sums"),
            add_offsets: pipe(
                "add_offsets",
                &[WORKGROUP_WGSL, &scan_per, scan],
                "add_offsets",
            ),
            gather: pipe(
                "gather",
                &[&ch, include_str!("../../shaders/gather.wgsl")],
                "main",
            ),
            emit: pipe(
                "emit",
                &[&VIEW_WGSL, include_str!("../../shaders/emit.wgsl")],
                "main",
            ),
            ranges: pipe(
                "tile_ranges",
                &[&VIEW_WGSL, include_str!("../../shaders/tile_ranges.wgsl")],
                "main",
            ),
            raster: pipe(
                "rasterize",
                &[
                    &ch,
                    &VIEW_WGSL,
                    LOAD_SURFEL_WGSL,
                    include_str!("../../shaders/rasterize.wgsl"),
                ],
                "main",
            ),
            raster_bwd: pipe(
                "rasterize_backward",
                &[
                    // The `diagnostic` directive in `lanes` must come first.
                    lanes,
                    &ch,
                    strategy.wgsl(),
                    &VIEW_WGSL,
                    LOAD_SURFEL_WGSL,
                    include_str!("../../shaders/rasterize_backward.wgsl"),
                ],
                "main",
            ),
            project_bwd: pipe(
                "project_backward",
                &[
                    &VIEW_WGSL,
                    GUARD_WGSL,
                    include_str!("../../shaders/project_backward.wgsl"),
                ],
                "main",
            ),
        }
    }
}

pub struct GpuRasterizer {
    k: RasterKernels,
    sorter: RadixSorter,
    /// Logit channels the compositing kernels were built for (`CH` in them).
    channels: u32,
    /// At most this many surfels per `gather` window (tests of the windowed path;
    /// `None`: as many as one storage binding holds).
    pub attr_window: Option<u32>,
}

/// Surfels per `gather` window are a multiple of this: 64 surfels' colours (768
/// bytes) and logits (256·channels bytes) start at offsets that every adapter's
/// storage offset alignment (at most 256 bytes) divides.
const ATTR_WINDOW_ALIGN: u32 = 64;

/// Floats per candidate slot of the view's `attrs`: rgb 3, then the logits.
pub fn attr_stride(channels: u32) -> u32 {
    3 + channels
}

/// The channel count of the compositing kernels, prepended to their source: their
/// per-pixel logit sums are arrays in registers, so the count is a constant of the
/// pipeline (any count; `CH_ARRAY` keeps the array non-empty when there are none).
fn channels_wgsl(channels: u32) -> String {
    format!(
        "const CH: u32 = {channels}u;\nconst CH_ARRAY: u32 = {}u;\n",
        channels.max(1)
    )
}

/// Surfel parameters on the GPU (structure of arrays).
pub struct GpuParams {
    pub pos: wgpu::Buffer,
    pub rotation: wgpu::Buffer,
    pub log_scale: wgpu::Buffer,
    pub opacity: wgpu::Buffer,
    pub rgb: wgpu::Buffer,
    pub logits: wgpu::Buffer,
    pub count: u32,
    pub channels: u32,
    /// Positions as uploaded, for the host's candidate lists (x and y never change;
    /// z within `candidates::Z_MARGIN`).
    pub xyz: Vec<[f32; 3]>,
}

impl GpuParams {
    /// The logits of surfels [first, end), for a kernel that binds one window of the
    /// model (`gather`, `adam`). Without channels nothing reads them, and the
    /// (padded) buffer is bound whole: an empty binding is invalid.
    pub fn logits_window(&self, first: u32, end: u32) -> wgpu::BufferBinding<'_> {
        let ch = self.channels as u64;
        if ch == 0 {
            return self.logits.as_entire_buffer_binding();
        }
        window(
            &self.logits,
            4 * ch * first as u64,
            4 * ch * (end - first) as u64,
        )
    }
}

/// Forward state kept for the backward pass.
pub struct GpuForward {
    /// Per pixel `PIX_STRIDE` floats: rgb 3, depth, alpha, final transmittance, last
    /// contributor (u32 bits), colour before exposure 3.
    pub px: wgpu::Buffer,
    pub logits: wgpu::Buffer,
    /// Per candidate slot: the projected surfel.
    pub proj: wgpu::Buffer,
    /// Per candidate slot: its surfel's colour and logits (`attr_stride` floats).
    pub attrs: wgpu::Buffer,
    /// Tiles each candidate touches (0: not in this view).
    pub counts: wgpu::Buffer,
    /// The view's candidate surfels, increasing: slot → surfel.
    pub cand: Vec<u32>,
    pub cand_buf: wgpu::Buffer,
    pub order: wgpu::Buffer,
    pub ranges: wgpu::Buffer,
    pub view: wgpu::Buffer,
    /// The surfel–tile pair count, when it was read back (`forward`); with a capacity
    /// (`forward_with`) it stays on the GPU in `total[0]`, and the pairs beyond
    /// `capacity` were dropped: the caller must check and render again if so.
    pub pairs: Option<u32>,
    pub total: wgpu::Buffer,
    pub capacity: u32,
    pub width: u32,
    pub height: u32,
    pub channels: u32,
}

/// Byte offset of (exposure_a, exposure_b) in the `View` uniform.
const VIEW_EXPOSURE_OFFSET: u64 = 4 * 23;
/// Byte offset of `frame_a`, the frame's log gain, in the `View` uniform (the
/// optimiser copies a gain measured in the step there: `optim::gain`).
pub const VIEW_FRAME_A_OFFSET: u64 = 4 * 30;

/// The `View` uniform of shaders/view.wgsl; `frame_a`: the frame's log gain on top
/// of the exposure (a, b).
fn view_bytes(
    cam: &ViewCamera,
    cull: &CullConfig,
    count: u32,
    channels: u32,
    masked: bool,
    comp: Compositing,
    frame_a: f32,
) -> Vec<u8> {
    let mut f: Vec<u32> = Vec::with_capacity(32);
    for row in &cam.world_to_cam {
        f.extend(row.iter().map(|v| v.to_bits()));
    }
    f.extend([cam.fx, cam.fy, cam.cx, cam.cy].map(f32::to_bits));
    f.extend([cam.width, cam.height, cam.tiles_x(), cam.tiles_y()]);
    f.extend([cull.near, cull.far, cull.half_width, cam.exposure[0]].map(f32::to_bits));
    f.extend([cam.exposure[1].to_bits(), tile_bits(cam), channels, count]);
    let average = comp == Compositing::Average;
    f.extend([masked as u32, average as u32, frame_a.to_bits(), 0]);
    bytemuck::cast_slice(&f).to_vec()
}

impl GpuRasterizer {
    /// Pipelines for models with `channels` logit channels, using the adapter's
    /// preferred gradient accumulation.
    pub async fn new(ctx: &GpuContext, channels: u32) -> Result<Self, GpuError> {
        Self::with_strategy(ctx, ctx.report.accumulation, ctx.report.subgroups, channels).await
    }

    /// Pipelines with an explicit accumulation strategy, reducing the backward pass's
    /// gradient adds over subgroups first or not (tests run every combination
    /// natively; `subgroups` needs the adapter's SUBGROUP feature).
    pub async fn with_strategy(
        ctx: &GpuContext,
        strategy: AccumStrategy,
        subgroups: bool,
        channels: u32,
    ) -> Result<Self, GpuError> {
        let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let me = Self {
            k: RasterKernels::new(ctx, strategy, subgroups, channels),
            sorter: RadixSorter::new(ctx).await?,
            channels,
            attr_window: None,
        };
        if let Some(e) = scope.pop().await {
            return Err(GpuError::Validation(e.to_string()));
        }
        Ok(me)
    }

    pub fn upload(ctx: &GpuContext, p: &Params<f32>) -> GpuParams {
        let flat = |v: Vec<f32>| bytemuck::cast_slice::<f32, u8>(&v).to_vec();
        GpuParams {
            pos: init_storage(ctx, "pos", &flat(p.pos.iter().flatten().copied().collect())),
            rotation: init_storage(
                ctx,
                "rotation",
                &flat(p.rotation.iter().flatten().copied().collect()),
            ),
            log_scale: init_storage(
                ctx,
                "log_scale",
                &flat(p.log_scale.iter().flatten().copied().collect()),
            ),
            opacity: init_storage(ctx, "opacity", &flat(p.opacity.clone())),
            rgb: init_storage(ctx, "rgb", &flat(p.rgb.iter().flatten().copied().collect())),
            logits: init_storage(ctx, "logits", &flat(p.logits.clone())),
            count: p.len() as u32,
            channels: p.channels as u32,
            xyz: p.pos.clone(),
        }
    }

    pub async fn forward(
        &self,
        ctx: &GpuContext,
        p: &GpuParams,
        cam: &ViewCamera,
        cull: &CullConfig,
    ) -> Result<GpuForward, GpuError> {
        self.forward_plain(ctx, p, cam, cull, Compositing::Occlusion, None)
            .await
    }

    /// The forward pass with neither exposure buffer, mask nor capacity.
    async fn forward_plain(
        &self,
        ctx: &GpuContext,
        p: &GpuParams,
        cam: &ViewCamera,
        cull: &CullConfig,
        comp: Compositing,
        fp: Option<&Footprints<'_>>,
    ) -> Result<GpuForward, GpuError> {
        let (e, m, c) = (None, None, None);
        self.forward_with(ctx, p, cam, cull, e, m, c, comp, fp)
            .await
    }

    /// The forward pass of the map's view from above (`Compositing::Average`); with
    /// `fp`, the candidates are the surfels whose own footprint reaches the window.
    pub async fn forward_map(
        &self,
        ctx: &GpuContext,
        p: &GpuParams,
        cam: &ViewCamera,
        cull: &CullConfig,
        fp: Option<&Footprints<'_>>,
    ) -> Result<GpuForward, GpuError> {
        self.forward_plain(ctx, p, cam, cull, Compositing::Average, fp)
            .await
    }

    /// The forward pass; with `exposure` = (buffer, byte offset), the view's exposure
    /// (a, b) is copied on the GPU from there instead of taken from `cam`, so that an
    /// optimiser can keep it on the GPU, and `cam.exposure[0]` is then the frame's
    /// own log gain on top of it (`View::frame_a`; `cam.exposure[1]` is unused). With
    /// `mask` (a packed training target, `loss::targets`), only the pixels inside the
    /// loss mask are composited; the others read as empty (training needs nothing
    /// else from them). With `capacity`, the pair buffers hold that many pairs and
    /// the count is not read back, so the whole pass is encoded without waiting for
    /// the GPU: the caller compares `total`
    /// with the capacity afterwards (the kernels clamp to it, so an overflow gives a
    /// wrong image, never an out-of-bounds access). `comp` says how a pixel combines
    /// its surfels (`Compositing`; the backward pass follows `Occlusion` only). `fp`:
    /// candidates by footprint (`Footprints`).
    #[allow(clippy::too_many_arguments)]
    pub async fn forward_with(
        &self,
        ctx: &GpuContext,
        p: &GpuParams,
        cam: &ViewCamera,
        cull: &CullConfig,
        exposure: Option<(&wgpu::Buffer, u64)>,
        mask: Option<&wgpu::Buffer>,
        capacity: Option<u32>,
        comp: Compositing,
        fp: Option<&Footprints<'_>>,
    ) -> Result<GpuForward, GpuError> {
        if p.channels != self.channels {
            return Err(GpuError::Failed(format!(
                "the model has {} logit channels, but the rasteriser was built for {}",
                p.channels, self.channels
            )));
        }
        let cand = candidates(&p.xyz, cam, cull, fp);
        let n = cand.len() as u32;
        let limit = ctx.limits.max_storage_buffer_binding_size;
        let per = candidate_bytes(p.channels as usize);
        if per * n as u64 > limit {
            return Err(GpuError::Validation(format!(
                "{n} surfels in one view need {} MiB in one GPU buffer, but this adapter binds at most {} MiB: use a coarser grid (--resolution) or a shorter culling box",
                (per * n as u64) >> 20,
                limit >> 20
            )));
        }
        let cand_buf = init_storage(ctx, "candidates", bytemuck::cast_slice(&cand));
        // With the exposure from a buffer, `cam.exposure[0]` is the frame's gain.
        let frame_a = if exposure.is_some() {
            cam.exposure[0]
        } else {
            0.0
        };
        let bytes = view_bytes(cam, cull, n, p.channels, mask.is_some(), comp, frame_a);
        let view = uniform(ctx, "view", &bytes);
        let (gx, gy) = ctx.dispatch_2d(n.div_ceil(256));
        let grid = uniform(ctx, "grid", bytemuck::cast_slice(&[gx * 256, 0u32, 0, 0]));
        let proj = storage(ctx, "proj", 4 * 24 * n as u64);
        let counts = storage(ctx, "tile_count", 4 * n as u64);
        let offsets = storage(ctx, "offsets", 4 * n as u64);
        // scan.wgsl: one invocation per block of `SCAN_PER` values.
        let blocks = n.div_ceil(SCAN_PER).max(1);
        let (bx, by) = ctx.dispatch_2d(blocks.div_ceil(256));
        let block_sums = storage(ctx, "block_sums", 4 * blocks as u64);
        let total = storage(ctx, "total", 16);
        let scan_params = uniform(
            ctx,
            "scan",
            bytemuck::cast_slice(&[n, blocks, bx * 256, gx * 256]),
        );
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        if let Some((buf, offset)) = exposure {
            enc.copy_buffer_to_buffer(buf, offset, &view, VIEW_EXPOSURE_OFFSET, 8);
        }
        let bg = bind(
            ctx,
            &self.k.project,
            &[
                (0, &view),
                (1, &p.pos),
                (2, &p.rotation),
                (3, &p.log_scale),
                (4, &p.opacity),
                (5, &proj),
                (6, &counts),
                (7, &grid),
                (8, &cand_buf),
            ],
        );
        dispatch(&mut enc, &self.k.project, &bg, (gx, gy, 1));
        let stride = attr_stride(p.channels) as u64;
        let attrs = storage(ctx, "attrs", 4 * stride * n as u64);
        self.encode_gather(ctx, &mut enc, p, &cand, &cand_buf, &attrs);
        // Auto layouts hold only the bindings an entry point uses.
        if n > 0 {
            let bg = bind(
                ctx,
                &self.k.scan_blocks,
                &[
                    (0, &counts),
                    (1, &offsets),
                    (2, &block_sums),
                    (4, &scan_params),
                ],
            );
            dispatch(&mut enc, &self.k.scan_blocks, &bg, (bx, by, 1));
        }
        let bg = bind(
            ctx,
            &self.k.scan_sums,
            &[(2, &block_sums), (3, &total), (4, &scan_params)],
        );
        dispatch(&mut enc, &self.k.scan_sums, &bg, (1, 1, 1));
        if n > 0 {
            let bg = bind(
                ctx,
                &self.k.add_offsets,
                &[(1, &offsets), (2, &block_sums), (4, &scan_params)],
            );
            dispatch(&mut enc, &self.k.add_offsets, &bg, (gx, gy, 1));
        }
        ctx.queue.submit([enc.finish()]);
        let max_pairs = ctx.limits.max_storage_buffer_binding_size / 4;
        let pairs = match capacity {
            Some(_) => None,
            None => {
                let t = read_bytes(ctx, &total, 4).await?;
                let pairs = u32::from_le_bytes([t[0], t[1], t[2], t[3]]);
                if pairs as u64 > max_pairs {
                    return Err(GpuError::Validation(format!(
                        "{pairs} surfel-tile pairs exceed the adapter's storage binding of {max_pairs} u32; render smaller views or fewer surfels"
                    )));
                }
                Some(pairs)
            }
        };
        let cap = capacity
            .or(pairs)
            .map_or(1, |c| (c as u64).clamp(1, max_pairs) as u32);
        let keys_a = storage(ctx, "keys_a", 4 * cap as u64);
        let values_a = storage(ctx, "values_a", 4 * cap as u64);
        let keys_b = storage(ctx, "keys_b", 4 * cap as u64);
        let values_b = storage(ctx, "values_b", 4 * cap as u64);
        let tiles = cam.tiles_x() * cam.tiles_y();
        let ranges = storage(ctx, "ranges", 8 * tiles as u64);
        let npx = (cam.width * cam.height) as u64;
        let ch = p.channels as u64;
        let out = GpuForward {
            px: storage(ctx, "px_out", 4 * PIX_STRIDE as u64 * npx),
            logits: storage(ctx, "out_logits", 4 * ch * npx),
            proj,
            attrs,
            counts: counts.clone(),
            cand,
            cand_buf,
            order: values_a.clone(),
            ranges: ranges.clone(),
            view,
            pairs,
            total: total.clone(),
            capacity: cap,
            width: cam.width,
            height: cam.height,
            channels: p.channels,
        };
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        let grid_cap = uniform(
            ctx,
            "grid_cap",
            bytemuck::cast_slice(&[gx * 256, cap, 0, 0]),
        );
        let bg = bind(
            ctx,
            &self.k.emit,
            &[
                (0, &out.view),
                (1, &out.proj),
                (2, &counts),
                (3, &offsets),
                (4, &keys_a),
                (5, &values_a),
                (6, &grid_cap),
            ],
        );
        dispatch(&mut enc, &self.k.emit, &bg, (gx, gy, 1));
        let scratch = self.sorter.scratch(ctx, cap);
        let pairs_in = SortPairs {
            keys_a: &keys_a,
            values_a: &values_a,
            keys_b: &keys_b,
            values_b: &values_b,
            count: &total,
        };
        let sorted = self
            .sorter
            .encode(ctx, &mut enc, &pairs_in, &scratch, cap, 32)?;
        let (keys, order) = match sorted {
            SortedIn::A => (&keys_a, &values_a),
            SortedIn::B => (&keys_b, &values_b),
        };
        enc.clear_buffer(&ranges, 0, None);
        let (px, py) = ctx.dispatch_2d(cap.div_ceil(256));
        let grid_pairs = uniform(
            ctx,
            "grid_pairs",
            bytemuck::cast_slice(&[px * 256, cap, 0, 0]),
        );
        let bg = bind(
            ctx,
            &self.k.ranges,
            &[
                (0, &out.view),
                (1, keys),
                (2, &total),
                (3, &ranges),
                (4, &grid_pairs),
            ],
        );
        dispatch(&mut enc, &self.k.ranges, &bg, (px, py, 1));
        let bg = bind(
            ctx,
            &self.k.raster,
            &[
                (0, &out.view),
                (1, &out.proj),
                (2, order),
                (3, &ranges),
                (4, &out.attrs),
                (6, &out.px),
                (7, &out.logits),
                (8, mask.unwrap_or(&ranges)),
            ],
        );
        dispatch(
            &mut enc,
            &self.k.raster,
            &bg,
            (cam.tiles_x(), cam.tiles_y(), 1),
        );
        ctx.queue.submit([enc.finish()]);
        Ok(GpuForward {
            order: order.clone(),
            ..out
        })
    }

    /// The model's surfel windows [first, end) that one `gather` pass binds: as many
    /// whole surfels as one storage binding holds (colours 12 bytes, logits
    /// 4·channels), a multiple of `ATTR_WINDOW_ALIGN`, at most `attr_window`.
    pub fn attr_windows(&self, ctx: &GpuContext, count: u32) -> Vec<(u32, u32)> {
        let per = (4 * self.channels as u64).max(12);
        let fit = (ctx.limits.max_storage_buffer_binding_size / per).min(u32::MAX as u64) as u32;
        let cap = fit.min(self.attr_window.unwrap_or(u32::MAX));
        let w = (cap / ATTR_WINDOW_ALIGN * ATTR_WINDOW_ALIGN).max(ATTR_WINDOW_ALIGN);
        (0..count.div_ceil(w))
            .map(|k| (k * w, (k.saturating_add(1).saturating_mul(w)).min(count)))
            .collect()
    }

    /// Records the `gather` passes: the colours and logits of the candidates `cand`
    /// (uploaded as `cand_buf`, increasing) into `attrs`, one model window per pass
    /// over the run of slots whose surfels lie in it.
    fn encode_gather(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        p: &GpuParams,
        cand: &[u32],
        cand_buf: &wgpu::Buffer,
        attrs: &wgpu::Buffer,
    ) {
        for (b0, b1) in self.attr_windows(ctx, p.count) {
            let s0 = cand.partition_point(|&c| c < b0);
            let s1 = cand.partition_point(|&c| c < b1);
            if s1 == s0 {
                continue;
            }
            let count = (s1 - s0) as u32;
            let (gx, gy) = ctx.dispatch_2d(count.div_ceil(256));
            let u = uniform(
                ctx,
                "gather",
                bytemuck::cast_slice(&[s0 as u32, count, b0, gx * 256]),
            );
            let (first, surfels) = (b0 as u64, (b1 - b0) as u64);
            let bg = bind_ranges(
                ctx,
                &self.k.gather,
                &[
                    (0, u.as_entire_buffer_binding()),
                    (1, cand_buf.as_entire_buffer_binding()),
                    (2, window(&p.rgb, 12 * first, 12 * surfels)),
                    (3, p.logits_window(b0, b1)),
                    (4, attrs.as_entire_buffer_binding()),
                ],
            );
            dispatch(enc, &self.k.gather, &bg, (gx, gy, 1));
        }
    }

    pub async fn read_image(ctx: &GpuContext, f: &GpuForward) -> Result<Image<f32>, GpuError> {
        let npx = (f.width * f.height) as usize;
        let ch = f.channels as usize;
        let px = read_f32(ctx, &f.px, PIX_STRIDE * npx).await?;
        let field = |k: usize| px.chunks_exact(PIX_STRIDE).map(move |p| p[k]);
        Ok(Image {
            width: f.width,
            height: f.height,
            rgb: px
                .chunks_exact(PIX_STRIDE)
                .flat_map(|p| [p[0], p[1], p[2]])
                .collect(),
            logits: read_f32(ctx, &f.logits, ch * npx).await?,
            depth: field(3).collect(),
            alpha: field(4).collect(),
            channels: ch,
        })
    }

    /// Records the backward pass: per-pixel loss gradients `g_px` (GRAD_STRIDE per
    /// pixel: rgb 3, depth, alpha) and `g_logits` to `view_grad`, which this clears
    /// first: `VIEW_GRAD + channels` floats per candidate slot (at least
    /// `view_grad_len` floats), then the exposure gradient d/da, d/db.
    /// `project_backward` leaves each candidate's parameter gradients at the head of
    /// its slot (`13 + channels`: position 3, rotation 4, log-scales 2, opacity, rgb
    /// 3, logits; `unpack_grads`). A gradient that is not usable (NaN,
    /// Inf or beyond 1e18) sets the u32 `status` to non-zero; it is not cleared here.
    #[allow(clippy::too_many_arguments)]
    pub fn encode_backward(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        p: &GpuParams,
        f: &GpuForward,
        g_px: &wgpu::Buffer,
        g_logits: &wgpu::Buffer,
        view_grad: &wgpu::Buffer,
        status: &wgpu::Buffer,
    ) {
        let n = f.cand.len() as u32;
        enc.clear_buffer(view_grad, 0, None);
        let bg = bind(
            ctx,
            &self.k.raster_bwd,
            &[
                (0, view_grad),
                (1, &f.view),
                (2, &f.proj),
                (3, &f.order),
                (4, &f.ranges),
                (5, &f.attrs),
                (7, &f.px),
                (8, g_px),
                (9, g_logits),
            ],
        );
        dispatch(
            enc,
            &self.k.raster_bwd,
            &bg,
            (f.width.div_ceil(TILE), f.height.div_ceil(TILE), 1),
        );
        // dispatch_2d gives at least one workgroup: slot 0 checks the exposure gradient.
        let (gx, gy) = ctx.dispatch_2d(n.div_ceil(256));
        let grid = uniform(ctx, "grid", bytemuck::cast_slice(&[gx * 256, 0u32, 0, 0]));
        let bg = bind(
            ctx,
            &self.k.project_bwd,
            &[
                (0, &f.view),
                (1, view_grad),
                (2, &p.rotation),
                (3, &p.log_scale),
                (4, status),
                (5, &grid),
                (6, &f.counts),
                (7, &f.cand_buf),
            ],
        );
        dispatch(enc, &self.k.project_bwd, &bg, (gx, gy, 1));
    }

    /// Parameter gradients of every surfel (same layout as `Params`, zero outside the
    /// view) and the exposure gradient, from per-pixel loss gradients on the host
    /// (tests and benchmarks).
    pub async fn backward(
        &self,
        ctx: &GpuContext,
        p: &GpuParams,
        f: &GpuForward,
        g: &OutputGrads<f32>,
    ) -> Result<(Params<f32>, [f32; 2]), GpuError> {
        let ch = p.channels as usize;
        let npx = (f.width * f.height) as usize;
        let packed: Vec<f32> = (0..npx)
            .flat_map(|i| {
                [
                    g.rgb[3 * i],
                    g.rgb[3 * i + 1],
                    g.rgb[3 * i + 2],
                    g.depth[i],
                    g.alpha[i],
                ]
            })
            .collect();
        let g_px = init_storage(ctx, "g_px", bytemuck::cast_slice(&packed));
        let g_logits = init_storage(ctx, "g_logits", bytemuck::cast_slice(&g.logits));
        let len = view_grad_len(f);
        let view_grad = storage(ctx, "view_grad", 4 * len as u64);
        let status = storage(ctx, "status", 4);
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        self.encode_backward(ctx, &mut enc, p, f, &g_px, &g_logits, &view_grad, &status);
        ctx.queue.submit([enc.finish()]);
        let flat = read_f32(ctx, &view_grad, len).await?;
        let (g, e) = unpack_grads(&flat, ch);
        Ok((scatter(&g, &f.cand, p.count as usize), e))
    }
}

/// GPU bytes a view holds per candidate while it is rendered and differentiated:
/// projected surfel 24 floats, tile count, offset, the candidate itself, colour and
/// logits 3 + channels, view gradients 18 + channels (pairs and pixels come on top,
/// per tile and pixel).
pub fn view_bytes_per_candidate(channels: u32) -> u64 {
    4 * (24 + 3 + attr_stride(channels) as u64 + VIEW_GRAD as u64 + channels as u64)
}

/// Floats of the view-gradient buffer `encode_backward` needs for forward pass `f`.
pub fn view_grad_len(f: &GpuForward) -> usize {
    (VIEW_GRAD + f.channels as usize) * f.cand.len() + 2
}

/// Per-candidate values (`Params` layout, one entry per slot) placed at their surfels
/// in a model of `n` surfels, zero elsewhere.
pub fn scatter(g: &Params<f32>, cand: &[u32], n: usize) -> Params<f32> {
    let ch = g.channels;
    let mut out = Params {
        channels: ch,
        pos: vec![[0.0; 3]; n],
        rotation: vec![[0.0; 4]; n],
        log_scale: vec![[0.0; 2]; n],
        opacity: vec![0.0; n],
        rgb: vec![[0.0; 3]; n],
        logits: vec![0.0; ch * n],
    };
    for (s, &i) in cand.iter().enumerate() {
        let i = i as usize;
        out.pos[i] = g.pos[s];
        out.rotation[i] = g.rotation[s];
        out.log_scale[i] = g.log_scale[s];
        out.opacity[i] = g.opacity[s];
        out.rgb[i] = g.rgb[s];
        out.logits[ch * i..ch * (i + 1)].copy_from_slice(&g.logits[ch * s..ch * (s + 1)]);
    }
    out
}

/// Splits the backward pass's `view_grad` buffer, read whole, into the parameter
/// gradients (`Params` layout) and the exposure gradient (d/da, d/db).
pub fn unpack_grads(flat: &[f32], ch: usize) -> (Params<f32>, [f32; 2]) {
    let stride = VIEW_GRAD + ch;
    let n = flat.len().saturating_sub(2) / stride;
    let mut out = Params {
        channels: ch,
        ..Default::default()
    };
    for s in flat[..n * stride].chunks_exact(stride) {
        out.pos.push([s[0], s[1], s[2]]);
        out.rotation.push([s[3], s[4], s[5], s[6]]);
        out.log_scale.push([s[7], s[8]]);
        out.opacity.push(s[9]);
        out.rgb.push([s[10], s[11], s[12]]);
        out.logits.extend_from_slice(&s[13..13 + ch]);
    }
    let e = [flat[n * stride], flat[n * stride + 1]];
    (out, e)
}
