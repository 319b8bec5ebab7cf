//! Host glue of one optimisation step on the GPU. Everything the step touches stays
//! on the GPU between steps (parameters, Adam moments, exposures, neighbour lists,
//! priors); per step the host uploads one packed target image and reads back the
//! rasteriser's pair count and a few kilobytes of loss partial sums.
//!
//! Step: `forward` → `loss` (per-pixel gradients) → read the loss; if it is not
//! finite, restore the last snapshot and stop → every `snapshot_every` steps copy the
//! parameters aside → `rasterize_backward` + `project_backward` → `regularise` →
//! `adam` (surfels) and `step_exposure` (this view's camera).

use super::adam::StepConstants;
use super::TrainConfig;
use crate::gpu::buffers::{bind, bytes_of, dispatch, init_storage, pipeline, storage, uniform};
use crate::gpu::readback::read_f32;
use crate::gpu::{GpuContext, GpuError};
use crate::loss::regularise::{RegData, RegWeights};
use crate::render::gpu::{GpuParams, GpuRasterizer};
use crate::render::rasterize_backward::VIEW_GRAD;
use crate::render::{Params, ViewCamera};
use thiserror::Error;

#[derive(Debug, Error)]
pub enum TrainError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error(
        "the loss became {value} at step {step}; optimisation stopped and the model of step \
         {good} was kept. Try a smaller z learning rate or check the bundle's poses"
    )]
    NonFinite {
        step: usize,
        good: usize,
        value: f64,
    },
}

/// Loss terms of one step (weighted), as the GPU summed them.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
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
}

pub struct Trainer {
    pub ctx: GpuContext,
    pub raster: GpuRasterizer,
    k: Kernels,
    pub params: GpuParams,
    snapshot: GpuParams,
    /// Step whose parameters the snapshot holds.
    snapshot_step: usize,
    grads: wgpu::Buffer,
    moments: wgpu::Buffer,
    view_grad: wgpu::Buffer,
    adj_start: wgpu::Buffer,
    adj: wgpu::Buffer,
    priors: wgpu::Buffer,
    /// (a, b) per camera.
    pub exposure: wgpu::Buffer,
    cameras: usize,
    reg: RegWeights,
    cfg: TrainConfig,
    /// Scene extent (m) that scales the z learning rate.
    extent: f32,
    total_steps: usize,
    pub steps_done: usize,
}

fn copy_params(enc: &mut wgpu::CommandEncoder, from: &GpuParams, to: &GpuParams) {
    for (a, b) in [
        (&from.pos, &to.pos),
        (&from.rotation, &to.rotation),
        (&from.log_scale, &to.log_scale),
        (&from.opacity, &to.opacity),
        (&from.rgb, &to.rgb),
        (&from.logits, &to.logits),
    ] {
        enc.copy_buffer_to_buffer(a, 0, b, 0, a.size());
    }
}

/// Every per-surfel buffer is bound whole, so the largest (the Adam moments,
/// 2 (13 + channels) floats per surfel, or the projected surfels, 24) must fit the
/// adapter's storage binding. Splitting the model into chunks is not done yet: until
/// then a model that does not fit is refused with what to change.
pub fn check_fits(ctx: &GpuContext, surfels: usize, channels: usize) -> Result<(), GpuError> {
    let per = 4 * (2 * (13 + channels)).max(24).max(VIEW_GRAD + channels) as u64;
    let limit = ctx.limits.max_storage_buffer_binding_size;
    let need = per * surfels as u64;
    if need > limit {
        return Err(GpuError::Validation(format!(
            "{surfels} surfels need {} MiB in one GPU buffer, but this adapter binds at most {} MiB ({} surfels with {channels} classes): use a coarser grid (--resolution), a narrower corridor (--half-width), or split the drive into shorter bundles",
            need >> 20,
            limit >> 20,
            limit / per
        )));
    }
    Ok(())
}

/// A (x, y) dispatch over `n` invocations in workgroups of 256, and its row stride.
fn grid_1d(ctx: &GpuContext, n: u32) -> ((u32, u32, u32), u32) {
    let (gx, gy) = ctx.dispatch_2d(n.div_ceil(256));
    ((gx, gy, 1), gx * 256)
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
    ) -> Result<Self, GpuError> {
        check_fits(&ctx, p.len(), p.channels)?;
        let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let raster = GpuRasterizer::new(&ctx).await?;
        let adam_src = include_str!("../../shaders/adam.wgsl");
        let k = Kernels {
            loss: pipeline(
                &ctx,
                "loss",
                &[include_str!("../../shaders/loss.wgsl")],
                "main",
            ),
            regularise: pipeline(
                &ctx,
                "regularise",
                &[include_str!("../../shaders/regularise.wgsl")],
                "main",
            ),
            adam: pipeline(&ctx, "adam", &[adam_src], "main"),
            exposure: pipeline(&ctx, "adam_exposure", &[adam_src], "step_exposure"),
        };
        let n = p.len() as u64;
        let stride = 13 + p.channels as u64;
        let params = GpuRasterizer::upload(&ctx, p);
        let snapshot = GpuRasterizer::upload(&ctx, p);
        let me = Self {
            grads: storage(&ctx, "grads", 4 * stride * n),
            moments: storage(&ctx, "moments", 4 * (2 * stride * n + 4 * cameras as u64)),
            view_grad: storage(
                &ctx,
                "view_grad",
                4 * ((VIEW_GRAD as u64 + p.channels as u64) * n + 2),
            ),
            adj_start: init_storage(&ctx, "adj_start", bytes_of(&reg.adj_start)),
            adj: init_storage(&ctx, "adj", bytes_of(&reg.adj)),
            priors: init_storage(&ctx, "priors", bytes_of(&reg.priors)),
            exposure: storage(&ctx, "exposure", 8 * cameras as u64),
            cameras,
            reg: reg.weights(&cfg.loss, cfg.use_lidar),
            cfg: cfg.clone(),
            extent,
            total_steps: total_steps.max(1),
            steps_done: 0,
            snapshot_step: 0,
            raster,
            k,
            params,
            snapshot,
            ctx,
        };
        if let Some(e) = scope.pop().await {
            return Err(GpuError::Validation(e.to_string()));
        }
        Ok(me)
    }

    /// GPU bytes held per surfel between steps: parameters, snapshot, gradients, Adam
    /// moments, view gradients, neighbour lists and priors.
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
            &self.grads,
            &self.moments,
            &self.view_grad,
            &self.adj_start,
            &self.adj,
            &self.priors,
        ]
        .iter()
        .map(|b| b.size())
        .sum();
        (2 * params + rest) as f64 / n
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
        let ctx = &self.ctx;
        let ch = self.params.channels;
        let camera = camera.min(self.cameras.saturating_sub(1));
        let f = self
            .raster
            .forward_with(
                ctx,
                &self.params,
                cam,
                &self.cfg.cull,
                Some((&self.exposure, 8 * camera as u64)),
            )
            .await?;
        let npx = cam.width * cam.height;
        let (groups, row) = grid_1d(ctx, npx);
        let lp: [u32; 8] = [
            cam.width,
            cam.height,
            ch,
            row,
            (1.0 / mask_count.max(1) as f32).to_bits(),
            self.cfg.loss.rgb.to_bits(),
            self.cfg.loss.ce.to_bits(),
            self.cfg.loss.min_alpha.to_bits(),
        ];
        let lp = uniform(ctx, "loss_params", bytes_of(&lp));
        let target = init_storage(ctx, "target", bytes_of(target));
        let g_px = storage(ctx, "g_px", 4 * 5 * npx as u64);
        let g_logits = storage(ctx, "g_logits", 4 * (ch * npx) as u64);
        let wgs = (groups.0 * groups.1) as usize;
        let partial = storage(ctx, "loss_partial", 8 * wgs as u64);
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        let bg = bind(
            ctx,
            &self.k.loss,
            &[
                (0, &lp),
                (1, &f.px),
                (2, &f.logits),
                (3, &target),
                (4, &g_px),
                (5, &g_logits),
                (6, &partial),
            ],
        );
        dispatch(&mut enc, &self.k.loss, &bg, groups);
        ctx.queue.submit([enc.finish()]);
        let sums = read_f32(ctx, &partial, 2 * wgs).await?;
        let mut loss = StepLoss::default();
        for s in sums.chunks_exact(2) {
            loss.rgb += s[0] as f64;
            loss.ce += s[1] as f64;
        }
        let step = self.steps_done;
        if !loss.total().is_finite() {
            let mut enc = ctx.device.create_command_encoder(&Default::default());
            copy_params(&mut enc, &self.snapshot, &self.params);
            ctx.queue.submit([enc.finish()]);
            return Err(TrainError::NonFinite {
                step,
                good: self.snapshot_step,
                value: loss.total(),
            });
        }
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        if step.is_multiple_of(self.cfg.snapshot_every.max(1)) {
            copy_params(&mut enc, &self.params, &self.snapshot);
            self.snapshot_step = step;
        }
        self.raster.encode_backward(
            ctx,
            &mut enc,
            &self.params,
            &f,
            &g_px,
            &g_logits,
            &self.view_grad,
            &self.grads,
        );
        let n = self.params.count;
        let stride = 13 + ch;
        let (sg, srow) = grid_1d(ctx, n);
        let w = &self.reg;
        let rp: [u32; 8] = [
            n,
            srow,
            stride,
            0,
            w.smooth.to_bits(),
            w.traj.to_bits(),
            w.huber.to_bits(),
            w.lidar.to_bits(),
        ];
        let rp = uniform(ctx, "reg_params", bytes_of(&rp));
        let swgs = (sg.0 * sg.1) as usize;
        let reg_partial = storage(ctx, "reg_partial", 12 * swgs as u64);
        let bg = bind(
            ctx,
            &self.k.regularise,
            &[
                (0, &rp),
                (1, &self.params.pos),
                (2, &self.adj_start),
                (3, &self.adj),
                (4, &self.priors),
                (5, &self.grads),
                (6, &reg_partial),
            ],
        );
        dispatch(&mut enc, &self.k.regularise, &bg, sg);
        let lr = &self.cfg.lr;
        let c = StepConstants::new(
            lr,
            lr.z_at(step, self.total_steps, self.extent),
            step as u32 + 1,
        );
        let au: [u32; 20] = [
            n,
            srow,
            stride,
            camera as u32,
            c.lr_z.to_bits(),
            c.lr_rotation.to_bits(),
            c.lr_scale.to_bits(),
            c.lr_opacity.to_bits(),
            c.lr_rgb.to_bits(),
            c.lr_logits.to_bits(),
            c.lr_exposure.to_bits(),
            c.beta1.to_bits(),
            c.beta2.to_bits(),
            c.eps.to_bits(),
            c.bias1.to_bits(),
            c.bias2.to_bits(),
            (VIEW_GRAD as u32 + ch) * n,
            0,
            0,
            0,
        ];
        let au = uniform(ctx, "adam_params", bytes_of(&au));
        let p = &self.params;
        let bg = bind(
            ctx,
            &self.k.adam,
            &[
                (0, &au),
                (1, &self.grads),
                (2, &self.moments),
                (3, &p.pos),
                (4, &p.rotation),
                (5, &p.log_scale),
                (6, &p.opacity),
                (7, &p.rgb),
                (8, &p.logits),
            ],
        );
        dispatch(&mut enc, &self.k.adam, &bg, sg);
        let bg = bind(
            ctx,
            &self.k.exposure,
            &[
                (0, &au),
                (2, &self.moments),
                (9, &self.view_grad),
                (10, &self.exposure),
            ],
        );
        dispatch(&mut enc, &self.k.exposure, &bg, (1, 1, 1));
        ctx.queue.submit([enc.finish()]);
        let sums = read_f32(ctx, &reg_partial, 3 * swgs).await?;
        // Out of memory or a lost device: stop with the words rather than train on.
        ctx.check()?;
        for s in sums.chunks_exact(3) {
            loss.smooth += s[0] as f64;
            loss.traj += s[1] as f64;
            loss.lidar += s[2] as f64;
        }
        self.steps_done += 1;
        Ok(loss)
    }

    /// The gradients of the last step (`Params` layout, regularisers included) and
    /// its exposure gradient (d/da, d/db).
    pub async fn read_grads(&self) -> Result<(Params<f32>, [f32; 2]), GpuError> {
        let n = self.params.count as usize;
        let ch = self.params.channels as usize;
        let flat = read_f32(&self.ctx, &self.grads, (13 + ch) * n).await?;
        let vg = read_f32(&self.ctx, &self.view_grad, (VIEW_GRAD + ch) * n + 2).await?;
        let e = [vg[vg.len() - 2], vg[vg.len() - 1]];
        Ok((crate::render::gpu::unpack_grads(&flat, ch), e))
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
