//! Host glue of one optimisation step on the GPU. Everything the step touches stays
//! on the GPU between steps (parameters, Adam moments, exposures, neighbour lists,
//! priors); per step the host uploads one packed target image and, once the whole
//! step is queued, reads back a few kilobytes: loss partial sums, status words and the
//! view's pair count. It does not wait for the GPU in the middle of a step.
//!
//! Step: `forward` (on the view's candidate surfels, `render::candidates`, with pair
//! buffers sized from the pairs per candidate seen so far) → at a view's first step
//! with frame gains, `frame_gain` (its gain from that forward pass, into the view
//! uniform: `optim::gain`) → `loss` (per-pixel
//! gradients) → `rasterize_backward` + `project_backward` (parameter gradients in
//! place in the per-candidate view gradients) → `regularise` (z gradients of every
//! surfel) → `adam` (dense, the default: every surfel, finding a candidate's slot
//! through membership words the host uploads with the candidates; with
//! `TrainConfig::adam` selective, both run over the candidates alone, so a step's cost
//! follows the view, not the model) and `step_exposure` (this view's camera), which
//! apply nothing when the status word is raised: by `loss` when the
//! loss is not finite or the pairs overflowed their capacity, by `project_backward`
//! and `regularise` when a gradient was not usable (shaders/guard.wgsl). An overflow
//! (rare: the capacity has a margin) runs the step again with the exact count.
//! Learning rates are checked when the trainer is made. Either way a NaN never
//! reaches the model, so the last good model is the current one and no copy of it is
//! kept.

use super::adam::{learnable, StepConstants};
use super::gain::{FrameGain, Measured};
use super::pose::{PoseGrad, PosePartials};
use super::TrainConfig;
use crate::gpu::buffers::{
    bind, bind_ranges, bytes_of, dispatch, init_storage, pipeline, storage, uniform, window,
};
use crate::gpu::partial_sums::PartialSums;
use crate::gpu::readback::read_f32;
use crate::gpu::{GpuContext, GpuError};
use crate::loss::regularise::{RegData, RegWeights};
use crate::render::candidates::membership;
use crate::render::gpu::{
    scatter, unpack_grads, view_grad_len, GpuParams, GpuRasterizer, GUARD_WGSL, VIEW_WGSL,
};
use crate::render::rasterize_backward::VIEW_GRAD;
use crate::render::{Params, ViewCamera};
use thiserror::Error;

#[derive(Debug, Error)]
pub enum TrainError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("{0}")]
    Settings(String),
    #[error(
        "{what} was not finite at step {step}; optimisation stopped and the model after \
         {kept} steps was kept. Try a smaller z learning rate or check the bundle's poses"
    )]
    NonFinite {
        step: usize,
        /// Steps whose updates the kept model holds.
        kept: usize,
        /// "the loss" or "a gradient".
        what: &'static str,
    },
}

/// Loss terms of one step (weighted), as the GPU summed them.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StepLoss {
    pub rgb: f64,
    pub ce: f64,
    pub smooth: f64,
    pub traj: f64,
    pub lidar: f64,
}

impl StepLoss {
    pub fn total(&self) -> f64 {
        self.rgb + self.ce + self.smooth + self.traj + self.lidar
    }
}

struct Kernels {
    loss: wgpu::ComputePipeline,
    regularise: wgpu::ComputePipeline,
    adam: wgpu::ComputePipeline,
    exposure: wgpu::ComputePipeline,
    /// The loss's and the regularisers' terms summed per 256 (`partial_sums`).
    loss_sums: PartialSums,
    reg_sums: PartialSums,
    /// `sync_known`: the z the host knows into the moments' blocks.
    sync: wgpu::ComputePipeline,
    pose: PoseGrad,
    gain: FrameGain,
}

impl Kernels {
    /// The trainer's pipelines (made once per device: `pipeline`'s cache).
    fn new(ctx: &GpuContext) -> Self {
        // The shaders' layout constants come from here, so host and kernel agree.
        let block = format!(
            "const BLOCK: u32 = {MOMENT_BLOCK}u;\nconst Z_MARGIN: f32 = {:?};",
            crate::render::candidates::Z_MARGIN
        );
        let adam_src = [
            block.as_str(),
            AdamParams::WGSL,
            include_str!("../../shaders/adam.wgsl"),
        ];
        let per = format!("const PER: u32 = {REGULARISE_PER}u;");
        Kernels {
            loss: pipeline(
                ctx,
                "loss",
                &[
                    &VIEW_WGSL,
                    LossParams::WGSL,
                    include_str!("../../shaders/loss.wgsl"),
                ],
                "main",
            ),
            regularise: pipeline(
                ctx,
                "regularise",
                &[
                    &VIEW_WGSL,
                    GUARD_WGSL,
                    &per,
                    RegParams::WGSL,
                    include_str!("../../shaders/regularise.wgsl"),
                ],
                "main",
            ),
            adam: pipeline(ctx, "adam", &adam_src, "main"),
            exposure: pipeline(ctx, "adam_exposure", &adam_src, "step_exposure"),
            sync: pipeline(ctx, "adam_sync_known", &adam_src, "sync_known"),
            loss_sums: PartialSums::new(ctx, "loss_sums", 2, true),
            reg_sums: PartialSums::new(ctx, "regularise_sums", 3, false),
            pose: PoseGrad::new(ctx),
            gain: FrameGain::new(ctx),
        }
    }
}

pub struct Trainer {
    pub ctx: GpuContext,
    pub raster: GpuRasterizer,
    k: Kernels,
    pub params: GpuParams,
    /// Adam moments in blocks of `MOMENT_BLOCK` surfels, slot-major within a block
    /// (shaders/adam.wgsl).
    moments: wgpu::Buffer,
    /// Surfel ranges [first, end), whole blocks, whose moments fit one storage
    /// binding: one `adam` pass each.
    windows: Vec<(u32, u32)>,
    /// Dense: the regularisers' z gradient per surfel, then the view's membership
    /// words; selective: (z gradient, surfel) per candidate slot.
    zreg: wgpu::Buffer,
    /// The last step's view gradients (parameter gradients in place) and candidates.
    last: Option<(wgpu::Buffer, Vec<u32>)>,
    /// Non-zero when a gradient of the step was not usable (`adam` then applies nothing).
    status: wgpu::Buffer,
    adj_start: wgpu::Buffer,
    adj: wgpu::Buffer,
    priors: wgpu::Buffer,
    /// (a, b) per camera, then their Adam moments (4 per camera).
    pub exposure: wgpu::Buffer,
    cameras: usize,
    reg: RegWeights,
    cfg: TrainConfig,
    /// Scene extent (m) that scales the z learning rate.
    extent: f32,
    total_steps: usize,
    pub steps_done: usize,
    /// Times a view found a surfel in its box that its candidate list missed (the
    /// host then read the positions back).
    pub position_refreshes: usize,
    /// Per camera, the most surfel–tile pairs a view has had: sizes the camera's next
    /// pair buffers (0: unknown, its first view reads the count back). Per camera,
    /// because the count follows the image and how the camera sees the road (on
    /// `demo` 130–155 k for the front camera, 14–26 k for the side ones); per
    /// candidate it is not stable (the candidates' box holds much that no camera sees).
    pairs_seen: Vec<u32>,
    /// Surfel–tile pairs of the last view stepped.
    last_pairs: u32,
    /// Steps run again because their pairs overflowed the capacity.
    pub pair_overflows: usize,
}

/// What a step gave besides the update.
#[derive(Clone, Copy, Debug, Default)]
pub struct StepOut {
    pub loss: StepLoss,
    /// dL/d(ω, τ), when a pose centre was given.
    pub pose: Option<[f64; 6]>,
    /// The view's gain, when the step measured it.
    pub gain: Option<Measured>,
}

/// What one try of a step ended with.
enum Try {
    Done(StepOut),
    /// The pairs overflowed the capacity; nothing was applied.
    Overflow,
}

/// The per-surfel buffers are bound whole, except the Adam moments and the logits
/// (4·channels bytes per surfel, the largest), which are bound one window of surfels
/// at a time (here and in the rasteriser's `gather`); so the largest of the rest (the
/// rotations and priors, 16 bytes per surfel, or the neighbour lists, `adj` words)
/// must fit the adapter's storage binding, and the moments its largest buffer. The
/// per-view buffers hold only the view's candidates (checked per view). A model that
/// does not fit is refused with what to change.
pub fn check_fits(
    ctx: &GpuContext,
    surfels: usize,
    channels: usize,
    adj: usize,
) -> Result<(), GpuError> {
    let advice = "use a coarser grid (--resolution), a narrower corridor (--half-width), or split the drive into shorter bundles";
    let limit = ctx.limits.max_storage_buffer_binding_size;
    let need = (16 * surfels as u64).max(4 * adj as u64);
    if need > limit {
        return Err(GpuError::Validation(format!(
            "{surfels} surfels need {} MiB in one GPU binding, but this adapter binds at most {} MiB (about {} surfels): {advice}",
            need >> 20,
            limit >> 20,
            limit / 16
        )));
    }
    let moments = moment_bytes(surfels as u32, learnable(channels) as u32);
    if moments > ctx.limits.max_buffer_size {
        return Err(GpuError::Validation(format!(
            "{surfels} surfels need {} MiB of Adam moments in one GPU buffer, but this adapter allows at most {} MiB per buffer: {advice}",
            moments >> 20,
            ctx.limits.max_buffer_size >> 20
        )));
    }
    Ok(())
}

crate::uniform_block! {
    /// The uniform of shaders/adam.wgsl.
    pub struct AdamParams {
        /// Surfels in the model.
        count: u32,
        /// Invocations per dispatch row (2D dispatches).
        row: u32,
        /// Floats per candidate's view-gradient slot.
        grad_stride: u32,
        /// This view's camera (its exposure).
        camera: u32,
        lr_z: f32,
        lr_rotation: f32,
        lr_scale: f32,
        lr_opacity: f32,
        lr_rgb: f32,
        lr_logits: f32,
        lr_exposure: f32,
        beta1: f32,
        beta2: f32,
        eps: f32,
        /// 1 − β1ᵗ and 1 − β2ᵗ.
        bias1: f32,
        bias2: f32,
        /// Where the exposure's gradient is in the view gradients.
        exposure_at: u32,
        channels: u32,
        cameras: u32,
        /// The first surfel of this pass (a multiple of the block: its window
        /// starts a block).
        first: u32,
        /// L, the learnable slots per surfel.
        learnable: u32,
        /// One past the last surfel of this pass.
        end: u32,
        /// 0: dense; 1: selective (candidate slots [cand_first, cand_end)).
        selective: u32,
        cand_first: u32,
        cand_end: u32,
        /// t, this step (from 1).
        step: u32,
        pad0: u32,
        pad1: u32,
    }
}

crate::uniform_block! {
    /// The uniform of shaders/loss.wgsl.
    pub struct LossParams {
        width: u32,
        height: u32,
        channels: u32,
        /// Invocations per dispatch row (2D dispatches).
        row: u32,
        /// 1 / the pixels the loss counts.
        inv_n: f32,
        w_rgb: f32,
        w_ce: f32,
        min_alpha: f32,
        /// The pairs the view's buffers hold (more: the step is refused).
        capacity: u32,
        /// The robust weighting's scale (0: plain L1).
        robust_c: f32,
        pad1: u32,
        pad2: u32,
    }
}

crate::uniform_block! {
    /// The uniform of shaders/regularise.wgsl.
    pub struct RegParams {
        count: u32,
        row: u32,
        /// 1: over the candidates (`cand_count` slots); 0: over every surfel.
        selective: u32,
        cand_count: u32,
        w_smooth: f32,
        w_traj: f32,
        huber: f32,
        w_lidar: f32,
    }
}

/// Surfels per block of Adam moments: the `adam` workgroup (`BLOCK` in
/// shaders/adam.wgsl), which `grid_1d`'s workgroups of 256 match.
const MOMENT_BLOCK: u32 = 256;

/// Surfels per `regularise` invocation (`PER` in shaders/regularise.wgsl).
const REGULARISE_PER: u32 = 8;

/// Bytes of one block's moments: m and v of every learnable slot, the step each surfel
/// was last stepped at and the z the host knows, for the block's surfels (a multiple
/// of 256, so every block starts at an allowed binding offset).
fn block_bytes(slots: u32) -> u64 {
    4 * (2 * slots as u64 + 2) * MOMENT_BLOCK as u64
}

/// Bytes of the moments of `n` surfels (whole blocks).
fn moment_bytes(n: u32, slots: u32) -> u64 {
    n.max(1).div_ceil(MOMENT_BLOCK) as u64 * block_bytes(slots)
}

/// The surfel windows [first, end), whole blocks, whose moments fit one binding, at
/// most `cap` blocks each.
fn moment_windows(ctx: &GpuContext, n: u32, slots: u32, cap: Option<usize>) -> Vec<(u32, u32)> {
    let fit = (ctx.limits.max_storage_buffer_binding_size / block_bytes(slots)).max(1) as u32;
    let per = MOMENT_BLOCK * fit.min(cap.map_or(u32::MAX, |c| c.max(1) as u32));
    (0..n.max(1).div_ceil(per))
        .map(|w| (w * per, ((w + 1) * per).min(n)))
        .collect()
}

/// A (x, y) dispatch over `n` invocations in workgroups of 256, and its row stride.
fn grid_1d(ctx: &GpuContext, n: u32) -> ((u32, u32, u32), u32) {
    let (gx, gy) = ctx.dispatch_2d(n.div_ceil(256));
    ((gx, gy, 1), gx * 256)
}

/// Compiles a run's training pipelines on `ctx` ahead of it, for a model of
/// `channels` logit channels: the rasteriser's, the radix sort's and the trainer's.
/// A trainer made later on the same device takes them from its cache instead of
/// compiling them (the page does this while its user looks at a dropped bundle:
/// SwiftShader takes 4–5 s over them). Resolves once the device has compiled them.
pub async fn warm_up(ctx: &GpuContext, channels: u32) -> Result<(), GpuError> {
    let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
    GpuRasterizer::new(ctx, channels.max(1)).await?;
    Kernels::new(ctx);
    match scope.pop().await {
        Some(e) => Err(GpuError::Validation(e.to_string())),
        None => Ok(()),
    }
}

impl Trainer {
    #[allow(clippy::too_many_arguments)]
    pub async fn new(
        ctx: GpuContext,
        p: &Params<f32>,
        reg: &RegData,
        cameras: usize,
        cfg: &TrainConfig,
        extent: f32,
        total_steps: usize,
    ) -> Result<Self, TrainError> {
        cfg.lr.check().map_err(TrainError::Settings)?;
        check_fits(&ctx, p.len(), p.channels, reg.adj.len())?;
        let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let mut raster = GpuRasterizer::new(&ctx, p.channels as u32).await?;
        // The rasteriser's logit windows follow the moments' (tests set both small).
        raster.attr_window = cfg
            .moment_window
            .map(|b| (b as u32).saturating_mul(MOMENT_BLOCK));
        let k = Kernels::new(&ctx);
        let n = p.len() as u64;
        let slots = learnable(p.channels) as u32;
        let windows = moment_windows(&ctx, n as u32, slots, cfg.moment_window);
        let params = GpuRasterizer::upload(&ctx, p);
        let me = Self {
            moments: storage(&ctx, "moments", moment_bytes(n as u32, slots)),
            windows,
            status: storage(&ctx, "status", 8),
            // Dense: n gradients and the membership words; selective: two words
            // per candidate.
            zreg: storage(&ctx, "zreg", 4 * (2 * n).max(n + 2 * n.div_ceil(32))),
            last: None,
            adj_start: init_storage(&ctx, "adj_start", bytes_of(&reg.adj_start)),
            adj: init_storage(&ctx, "adj", bytes_of(&reg.adj)),
            priors: init_storage(&ctx, "priors", bytes_of(&reg.priors)),
            exposure: storage(&ctx, "exposure", 24 * cameras as u64),
            cameras,
            reg: reg.weights(&cfg.loss, cfg.use_lidar),
            cfg: cfg.clone(),
            extent,
            total_steps: total_steps.max(1),
            steps_done: 0,
            position_refreshes: 0,
            pairs_seen: vec![0; cameras.max(1)],
            last_pairs: 0,
            pair_overflows: 0,
            raster,
            k,
            params,
            ctx,
        };
        me.sync_known();
        if let Some(e) = scope.pop().await {
            return Err(GpuError::Validation(e.to_string()).into());
        }
        Ok(me)
    }

    /// Copies the z of every surfel, as the host now knows it, into the moments'
    /// blocks (`sync_known` of shaders/adam.wgsl), for selective Adam's margin check
    /// (dense Adam's check is `regularise`'s and reads none of it).
    fn sync_known(&self) {
        if self.cfg.adam != super::AdamScope::Selective {
            return;
        }
        let ctx = &self.ctx;
        let slots = learnable(self.params.channels as usize) as u32;
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        for &(first, end) in &self.windows {
            let (wg, row) = grid_1d(ctx, end - first);
            let u = AdamParams {
                count: self.params.count,
                row,
                first,
                learnable: slots,
                end,
                ..AdamParams::default()
            };
            let u = uniform(ctx, "adam_sync_params", bytemuck::bytes_of(&u));
            let moments = window(
                &self.moments,
                (first / MOMENT_BLOCK) as u64 * block_bytes(slots),
                moment_bytes(end - first, slots),
            );
            let k = &self.k.sync;
            let bg = bind_ranges(
                ctx,
                k,
                &[
                    (0, u.as_entire_buffer_binding()),
                    (2, moments),
                    (3, self.params.pos.as_entire_buffer_binding()),
                ],
            );
            dispatch(&mut enc, k, &bg, wg);
        }
        ctx.queue.submit([enc.finish()]);
    }

    /// GPU bytes held per surfel between steps: parameters, Adam moments, z gradients
    /// and membership words, neighbour lists and priors. The per-view buffers
    /// (`view_bytes_per_candidate` per candidate) are made per step and not counted.
    pub fn bytes_per_surfel(&self) -> f64 {
        let n = self.params.count.max(1) as f64;
        let p = &self.params;
        let params: u64 = [
            &p.pos,
            &p.rotation,
            &p.log_scale,
            &p.opacity,
            &p.rgb,
            &p.logits,
        ]
        .iter()
        .map(|b| b.size())
        .sum();
        let rest: u64 = [
            &self.moments,
            &self.zreg,
            &self.adj_start,
            &self.adj,
            &self.priors,
        ]
        .iter()
        .map(|b| b.size())
        .sum();
        (params + rest) as f64 / n
    }

    /// One optimisation step on view `cam` of camera `camera` with its packed target
    /// (`targets::pack`) and mask count.
    pub async fn step(
        &mut self,
        cam: &ViewCamera,
        camera: usize,
        target: &[u32],
        mask_count: usize,
    ) -> Result<StepLoss, TrainError> {
        Ok(self
            .step_with(cam, camera, target, mask_count, None, false)
            .await?
            .loss)
    }

    /// `step`, and with `pose_centre` (the view's vehicle position, local frame) also
    /// the rendering loss's gradient with respect to a correction of the view's
    /// vehicle pose about it (`optim::pose`), dL/d(ω, τ). With `measure_gain` the
    /// view's own gain is measured from the step's forward pass (rendered with
    /// `cam.exposure[0]`, the frame gain, as given: 0 for a view not yet measured)
    /// and the step trains at it (`optim::gain`).
    pub async fn step_with(
        &mut self,
        cam: &ViewCamera,
        camera: usize,
        target: &[u32],
        mask_count: usize,
        pose_centre: Option<[f32; 3]>,
        measure_gain: bool,
    ) -> Result<StepOut, TrainError> {
        let target = init_storage(&self.ctx, "target", bytes_of(target));
        let camera = camera.min(self.cameras.saturating_sub(1));
        let mut capacity = self.pair_capacity(camera);
        loop {
            match self
                .try_step(
                    cam,
                    camera,
                    &target,
                    mask_count,
                    capacity,
                    pose_centre,
                    measure_gain,
                )
                .await?
            {
                Try::Done(out) => return Ok(out),
                Try::Overflow => {
                    self.pair_overflows += 1;
                    capacity = None;
                }
            }
        }
    }

    /// Pairs to size a view of `camera` for: the most seen × the margin; `None` (read
    /// the count back) before the camera's first view.
    fn pair_capacity(&self, camera: usize) -> Option<u32> {
        let seen = self.pairs_seen[camera] as f64;
        (seen > 0.0).then(|| (seen * self.cfg.pair_margin).ceil().min(u32::MAX as f64) as u32)
    }

    /// The step with pair buffers for `capacity` pairs (`None`: the exact count, read
    /// back).
    #[allow(clippy::too_many_arguments)]
    async fn try_step(
        &mut self,
        cam: &ViewCamera,
        camera: usize,
        target: &wgpu::Buffer,
        mask_count: usize,
        capacity: Option<u32>,
        pose_centre: Option<[f32; 3]>,
        measure_gain: bool,
    ) -> Result<Try, TrainError> {
        let ctx = &self.ctx;
        let ch = self.params.channels;
        // Only the loss's pixels are composited: the rest would get no gradient.
        let f = self
            .raster
            .forward_with(
                ctx,
                &self.params,
                cam,
                &self.cfg.cull,
                Some((&self.exposure, 8 * camera as u64)),
                Some(target),
                capacity,
                crate::render::Compositing::Occlusion,
                None,
            )
            .await?;
        let npx = cam.width * cam.height;
        let (groups, row) = grid_1d(ctx, npx);
        let lp = LossParams {
            width: cam.width,
            height: cam.height,
            channels: ch,
            row,
            inv_n: 1.0 / mask_count.max(1) as f32,
            w_rgb: self.cfg.loss.rgb,
            w_ce: self.cfg.loss.ce,
            min_alpha: self.cfg.loss.min_alpha,
            capacity: f.capacity,
            robust_c: self.cfg.loss.robust_c,
            ..LossParams::default()
        };
        let lp = uniform(ctx, "loss_params", bytemuck::bytes_of(&lp));
        let g_px = storage(ctx, "g_px", 4 * 5 * npx as u64);
        let g_logits = storage(ctx, "g_logits", 4 * (ch * npx) as u64);
        // The pixels' terms (every dispatched invocation's slot: the padding stays
        // zero), then their sums per 256 pixels, which the host reads.
        let terms = storage(ctx, "loss_terms", 8 * 256 * (groups.0 * groups.1) as u64);
        let wgs = PartialSums::runs(npx) as usize;
        let partial = storage(ctx, "loss_partial", 8 * wgs.max(1) as u64);
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&self.status, 0, None);
        // The view's gain, into its uniform before the loss reads it.
        let gain = measure_gain.then(|| {
            self.k
                .gain
                .encode(ctx, &mut enc, &f, target, self.cfg.loss.min_alpha)
        });
        let bg = bind(
            ctx,
            &self.k.loss,
            &[
                (0, &lp),
                (1, &f.px),
                (2, &f.logits),
                (3, target),
                (4, &g_px),
                (5, &g_logits),
                (6, &terms),
                (7, &self.status),
                (8, &f.total),
                (9, &f.view),
            ],
        );
        dispatch(&mut enc, &self.k.loss, &bg, groups);
        self.k
            .loss_sums
            .encode(ctx, &mut enc, &terms, npx, &partial, &self.status);
        let step = self.steps_done;
        let n = self.params.count;
        let view_grad = storage(ctx, "view_grad", 4 * view_grad_len(&f) as u64);
        let mode = self.cfg.adam;
        // Regularisers and `adam` over the candidate slots alone.
        let selective = mode == super::AdamScope::Selective;
        let nc = f.cand.len() as u32;
        if !selective {
            let words = membership(&f.cand, n as usize);
            ctx.queue
                .write_buffer(&self.zreg, 4 * n as u64, bytemuck::cast_slice(&words));
        }
        self.raster.encode_backward(
            ctx,
            &mut enc,
            &self.params,
            &f,
            &g_px,
            &g_logits,
            &view_grad,
            &self.status,
        );
        let stride = VIEW_GRAD as u32 + ch;
        // Before `adam` reads the slots (it does not write them, but keep the order
        // the header of pose_grad.wgsl states).
        let pose = pose_centre.map(|c| {
            self.k
                .pose
                .encode(ctx, &mut enc, &self.params, &f, &view_grad, c)
        });
        let pose_floats = pose.as_ref().map_or(0, |p| 6 * p.groups);
        // Selective: over the candidate slots; dense: over every surfel.
        let over = if selective { nc } else { n };
        let (sg, srow) = grid_1d(ctx, over.div_ceil(REGULARISE_PER));
        let w = &self.reg;
        let rp = RegParams {
            count: n,
            row: srow,
            selective: selective as u32,
            cand_count: nc,
            w_smooth: w.smooth,
            w_traj: w.traj,
            huber: w.huber,
            w_lidar: w.lidar,
        };
        let rp = uniform(ctx, "reg_params", bytemuck::bytes_of(&rp));
        let swgs = (sg.0 * sg.1) as usize;
        // Each invocation's terms, summed per 256 invocations by `regularise_sums`.
        let reg_terms = storage(ctx, "regularise_terms", 4 * 3 * 256 * swgs as u64);
        // Read back at the end: the regulariser's partial sums, the two status words,
        // the pair count, the loss's partial sums, the pose's and the gain's words.
        let tail = 3 * swgs;
        let gain_floats = if gain.is_some() { 4 } else { 0 };
        let readback = storage(
            ctx,
            "step_readback",
            4 * (tail + 3 + 2 * wgs + pose_floats + gain_floats) as u64,
        );
        let bg = bind(
            ctx,
            &self.k.regularise,
            &[
                (0, &rp),
                (1, &self.params.pos),
                (2, &self.adj_start),
                (3, &self.adj),
                (4, &self.priors),
                (5, &self.zreg),
                (6, &reg_terms),
                (7, &self.status),
                (8, &f.view),
                (9, &f.cand_buf),
            ],
        );
        dispatch(&mut enc, &self.k.regularise, &bg, sg);
        // Into the readback's head: the host sums the triples.
        self.k.reg_sums.encode(
            ctx,
            &mut enc,
            &reg_terms,
            256 * swgs as u32,
            &readback,
            &self.status,
        );
        let lr = &self.cfg.lr;
        let c = StepConstants::new(
            lr,
            lr.z_at(step, self.total_steps, self.extent),
            step as u32 + 1,
        );
        let slots = learnable(ch as usize) as u32;
        let au =
            |(first, end): (u32, u32), row: u32, (cand_first, cand_end): (u32, u32)| AdamParams {
                count: n,
                row,
                grad_stride: stride,
                camera: camera as u32,
                lr_z: c.lr_z,
                lr_rotation: c.lr_rotation,
                lr_scale: c.lr_scale,
                lr_opacity: c.lr_opacity,
                lr_rgb: c.lr_rgb,
                lr_logits: c.lr_logits,
                lr_exposure: c.lr_exposure,
                beta1: c.beta1,
                beta2: c.beta2,
                eps: c.eps,
                bias1: c.bias1,
                bias2: c.bias2,
                exposure_at: stride * f.cand.len() as u32,
                channels: ch,
                cameras: self.cameras as u32,
                first,
                learnable: slots,
                end,
                selective: mode.code(),
                cand_first,
                cand_end,
                step: step as u32 + 1,
                pad0: 0,
                pad1: 0,
            };
        let p = &self.params;
        // One pass per window of blocks whose moments fit one binding (usually one).
        let k = &self.k.adam;
        for &(first, end) in &self.windows {
            // Selective: the candidate slots whose surfels lie in the window.
            let s0 = f.cand.partition_point(|&c| c < first) as u32;
            let s1 = f.cand.partition_point(|&c| c < end) as u32;
            if selective && s1 == s0 {
                continue;
            }
            let (wg, row) = grid_1d(ctx, if selective { s1 - s0 } else { end - first });
            let u = uniform(
                ctx,
                "adam_params",
                bytemuck::bytes_of(&au((first, end), row, (s0, s1))),
            );
            let moments = window(
                &self.moments,
                (first / MOMENT_BLOCK) as u64 * block_bytes(slots),
                moment_bytes(end - first, slots),
            );
            let bg = bind_ranges(
                ctx,
                k,
                &[
                    (0, u.as_entire_buffer_binding()),
                    (1, view_grad.as_entire_buffer_binding()),
                    (2, moments),
                    (3, p.pos.as_entire_buffer_binding()),
                    (4, p.rotation.as_entire_buffer_binding()),
                    (5, p.log_scale.as_entire_buffer_binding()),
                    (6, p.opacity.as_entire_buffer_binding()),
                    (7, p.rgb.as_entire_buffer_binding()),
                    // The same surfels' logits (a block of 256 starts at a multiple of 1 KiB).
                    (8, p.logits_window(first, end)),
                    (10, self.status.as_entire_buffer_binding()),
                    (11, self.zreg.as_entire_buffer_binding()),
                ],
            );
            dispatch(&mut enc, k, &bg, wg);
        }
        // Auto layouts hold only what an entry uses: the exposure's step needs no
        // surfel buffers.
        let au = uniform(
            ctx,
            "adam_params",
            bytemuck::bytes_of(&au((0, 0), 0, (0, 0))),
        );
        let e = &self.k.exposure;
        let bg = bind(
            ctx,
            e,
            &[
                (0, &au),
                (1, &view_grad),
                (9, &self.exposure),
                (10, &self.status),
            ],
        );
        dispatch(&mut enc, e, &bg, (1, 1, 1));
        let at = |k: usize| 4 * k as u64;
        enc.copy_buffer_to_buffer(&self.status, 0, &readback, at(tail), 8);
        enc.copy_buffer_to_buffer(&f.total, 0, &readback, at(tail + 2), 4);
        enc.copy_buffer_to_buffer(&partial, 0, &readback, at(tail + 3), at(2 * wgs));
        let pose_at = tail + 3 + 2 * wgs;
        if let Some(p) = &pose {
            enc.copy_buffer_to_buffer(&p.buffer, 0, &readback, at(pose_at), at(pose_floats));
        }
        let gain_at = pose_at + pose_floats;
        if let Some(g) = &gain {
            enc.copy_buffer_to_buffer(g, 0, &readback, at(gain_at), at(gain_floats));
        }
        ctx.queue.submit([enc.finish()]);
        let sums = read_f32(ctx, &readback, gain_at + gain_floats).await?;
        let pose = pose.map(|_| PosePartials::sum(&sums[pose_at..gain_at]));
        let gain = gain.map(|_| Measured::from_words(&sums[gain_at..]));
        // Out of memory or a lost device: stop with the words rather than train on.
        ctx.check()?;
        let pairs = sums[tail + 2].to_bits();
        self.last_pairs = pairs;
        let seen = &mut self.pairs_seen[camera];
        *seen = (*seen).max(pairs);
        if pairs > f.capacity {
            return Ok(Try::Overflow);
        }
        self.last = Some((view_grad, f.cand));
        let mut loss = StepLoss::default();
        for s in sums[tail + 3..pose_at].chunks_exact(2) {
            loss.rgb += s[0] as f64;
            loss.ce += s[1] as f64;
        }
        if sums[tail].to_bits() != 0 {
            let what = if loss.total().is_finite() {
                "a gradient"
            } else {
                "the loss"
            };
            return Err(TrainError::NonFinite {
                step,
                kept: step,
                what,
            });
        }
        for s in sums[..tail].chunks_exact(3) {
            loss.smooth += s[0] as f64;
            loss.traj += s[1] as f64;
            loss.lidar += s[2] as f64;
        }
        self.steps_done += 1;
        // A surfel in the box was not a candidate: its z moved beyond the host's margin
        // since the positions were uploaded. Learn where the surfels are now, so that
        // the next view lists it (this step rendered without it).
        if sums[tail + 1].to_bits() != 0 {
            self.refresh_positions().await?;
        }
        // Gradients were usable and the update is in, but a regulariser's loss is not
        // finite (a NaN prior can give a clamped, finite gradient): stop here too.
        if !loss.total().is_finite() {
            return Err(TrainError::NonFinite {
                step,
                kept: self.steps_done,
                what: "the loss",
            });
        }
        Ok(Try::Done(StepOut { loss, pose, gain }))
    }

    /// Reads the positions back into the host's copy that candidate lists use (and
    /// selective Adam's margin check).
    async fn refresh_positions(&mut self) -> Result<(), GpuError> {
        let pos = read_f32(&self.ctx, &self.params.pos, 3 * self.params.count as usize).await?;
        self.params.xyz = pos.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        self.sync_known();
        self.position_refreshes += 1;
        Ok(())
    }

    /// The gradients of the last step (`Params` layout, regularisers included) and
    /// its exposure gradient (d/da, d/db); `None` before the first step.
    pub async fn read_grads(&self) -> Result<Option<(Params<f32>, [f32; 2])>, GpuError> {
        let Some((view_grad, cand)) = &self.last else {
            return Ok(None);
        };
        let n = self.params.count as usize;
        let ch = self.params.channels as usize;
        let flat = read_f32(&self.ctx, view_grad, (VIEW_GRAD + ch) * cand.len() + 2).await?;
        let (g, e) = unpack_grads(&flat, ch);
        let mut g = scatter(&g, cand, n);
        if self.cfg.adam == super::AdamScope::Selective {
            let zreg = read_f32(&self.ctx, &self.zreg, 2 * cand.len()).await?;
            for (z, &i) in zreg.chunks_exact(2).zip(cand) {
                g.pos[i as usize][2] += z[0];
            }
        } else {
            let zreg = read_f32(&self.ctx, &self.zreg, n).await?;
            for (p, z) in g.pos.iter_mut().zip(zreg) {
                p[2] += z;
            }
        }
        Ok(Some((g, e)))
    }

    /// Candidates of the last step's view (0 before the first step).
    pub fn last_candidates(&self) -> usize {
        self.last.as_ref().map_or(0, |l| l.1.len())
    }

    /// Surfel–tile pairs of the last view stepped (what the rasteriser sorted).
    pub fn last_pairs(&self) -> u32 {
        self.last_pairs
    }

    /// The current parameters, read back.
    pub async fn read_params(&self) -> Result<Params<f32>, GpuError> {
        read_params(&self.ctx, &self.params).await
    }

    /// The current exposure (a, b) of every camera.
    pub async fn read_exposures(&self) -> Result<Vec<[f32; 2]>, GpuError> {
        let e = read_f32(&self.ctx, &self.exposure, 2 * self.cameras).await?;
        Ok(e.chunks_exact(2).map(|v| [v[0], v[1]]).collect())
    }
}

/// Reads surfel parameters back from the GPU.
pub async fn read_params(ctx: &GpuContext, p: &GpuParams) -> Result<Params<f32>, GpuError> {
    let n = p.count as usize;
    let ch = p.channels as usize;
    let v3 = |v: Vec<f32>| v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    Ok(Params {
        pos: v3(read_f32(ctx, &p.pos, 3 * n).await?),
        rotation: read_f32(ctx, &p.rotation, 4 * n)
            .await?
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect(),
        log_scale: read_f32(ctx, &p.log_scale, 2 * n)
            .await?
            .chunks_exact(2)
            .map(|c| [c[0], c[1]])
            .collect(),
        opacity: read_f32(ctx, &p.opacity, n).await?,
        rgb: v3(read_f32(ctx, &p.rgb, 3 * n).await?),
        logits: read_f32(ctx, &p.logits, ch * n).await?,
        channels: ch,
    })
}
