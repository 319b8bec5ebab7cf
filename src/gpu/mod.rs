//! GPU context: one place that finds an adapter and a device, natively (honouring
//! `WGPU_BACKEND`) and in the browser (async), and reports what it found.
//!
//! The report decides how kernels accumulate gradients: where the adapter has native
//! `atomic<f32>` add (Vulkan drivers such as lavapipe) we use it; browsers have none,
//! so there kernels use a compare-and-swap loop on `atomic<u32>` bit patterns.

pub mod buffers;
pub mod contract;
pub mod partial_sums;
pub mod radix_sort;
pub mod readback;
pub mod scatter_add;
pub mod timing;

/// `workgroup_scan` (shaders/workgroup.wgsl): a 256-invocation workgroup's prefix
/// sum in three barriers, prepended to the kernels that scan per workgroup.
pub const WORKGROUP_WGSL: &str = include_str!("../../shaders/workgroup.wgsl");

use serde::Serialize;
use thiserror::Error;

#[derive(Debug, Error)]
pub enum GpuError {
    #[error("no GPU adapter found ({0}). {hint}", hint = no_adapter_hint())]
    NoAdapter(String),
    #[error("the GPU adapter refused a device ({0}); try updating the graphics driver or browser")]
    RequestDevice(String),
    #[error("GPU buffer read-back failed: {0}")]
    Readback(String),
    #[error("GPU error: {0}")]
    Validation(String),
    #[error("{0}")]
    Failed(String),
}

/// What to install or enable when no adapter is found.
pub fn no_adapter_hint() -> &'static str {
    if cfg!(target_arch = "wasm32") {
        "This page needs WebGPU: use a current Chrome, Edge or another Chromium-based browser \
         (version 113 or newer) with hardware acceleration on; on Linux start Chromium with \
         --enable-unsafe-webgpu --enable-features=Vulkan; in Firefox Nightly set dom.webgpu.enabled."
    } else {
        "Install a Vulkan driver: on a machine without a GPU, Mesa's software driver \
         (Debian/Ubuntu: `apt-get install mesa-vulkan-drivers libvulkan1`) and run with \
         WGPU_BACKEND=vulkan; on a machine with a GPU, its vendor's Vulkan driver."
    }
}

/// How kernels add floats into shared gradient buffers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum AccumStrategy {
    /// `atomicAdd` on `atomic<f32>` (needs `SHADER_FLOAT32_ATOMIC`; native only).
    NativeF32,
    /// Compare-and-swap loop on the `u32` bit pattern of an f32 (works everywhere).
    CasU32,
}

impl AccumStrategy {
    /// WGSL that declares `accum` at `@group(0) @binding(0)` and `fn accum_add(i, v)`.
    pub fn wgsl(self) -> &'static str {
        match self {
            AccumStrategy::NativeF32 => include_str!("../../shaders/accum_f32.wgsl"),
            AccumStrategy::CasU32 => include_str!("../../shaders/accum_cas.wgsl"),
        }
    }
}

/// The adapter as reported to users and benchmarks.
#[derive(Clone, Debug, Serialize)]
pub struct AdapterReport {
    pub name: String,
    pub backend: String,
    pub device_type: String,
    pub driver: String,
    pub features: Vec<String>,
    pub max_storage_buffer_binding_size: u64,
    pub max_buffer_size: u64,
    pub max_compute_invocations_per_workgroup: u32,
    pub max_compute_workgroup_storage_size: u32,
    pub max_compute_workgroups_per_dimension: u32,
    pub subgroups: bool,
    pub timestamps: bool,
    pub accumulation: AccumStrategy,
}

impl AdapterReport {
    pub fn to_text(&self) -> String {
        format!(
            "adapter      {} ({}, {}, driver {})\n\
             storage      {} MiB per binding, {} MiB per buffer\n\
             workgroups   {} invocations, {} KiB shared, {} per dimension\n\
             subgroups    {}\ntimestamps   {}\naccumulation {:?}\nfeatures     {}\n",
            self.name,
            self.backend,
            self.device_type,
            self.driver,
            self.max_storage_buffer_binding_size >> 20,
            self.max_buffer_size >> 20,
            self.max_compute_invocations_per_workgroup,
            self.max_compute_workgroup_storage_size >> 10,
            self.max_compute_workgroups_per_dimension,
            self.subgroups,
            self.timestamps,
            self.accumulation,
            self.features.join(", ")
        )
    }
}

/// Device, queue and what they can do. Cloning shares the device (its handles are
/// reference-counted): the tiles of a run each hold one.
#[derive(Clone)]
pub struct GpuContext {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub report: AdapterReport,
    pub features: wgpu::Features,
    pub limits: wgpu::Limits,
    /// The first GPU error no error scope caught (out of memory, a lost device, a
    /// validation error): recorded instead of panicking, and returned by `check()`.
    failure: std::sync::Arc<std::sync::Mutex<Option<String>>>,
    /// Set by the device-lost callback (`is_lost`).
    lost: std::sync::Arc<std::sync::atomic::AtomicBool>,
    /// The compute pipelines made on this device, by label, entry and source
    /// (`buffers::pipeline`): each tile's trainer and rasteriser reuse them instead
    /// of compiling them again (the page spends 4–5 s setting up the GPU for a run,
    /// mostly on them).
    pipelines: std::sync::Arc<std::sync::Mutex<PipelineCache>>,
    /// The radix sort's kernels (their own layout keeps them out of `pipelines`),
    /// kept with the pipelines and dropped with them (`start_tile`).
    sorter: std::sync::Arc<std::sync::Mutex<Option<radix_sort::RadixSorter>>>,
    /// Compute pipelines compiled on this device so far (cache misses).
    compiled: std::sync::Arc<std::sync::atomic::AtomicUsize>,
}

/// Compute pipelines by (label, entry point, WGSL parts).
type PipelineCache =
    std::collections::HashMap<(String, String, Vec<String>), wgpu::ComputePipeline>;

impl GpuContext {
    /// Bytes of GPU memory the device has reserved now (native Vulkan: wgpu's
    /// allocator report); `None` where the backend does not say (WebGPU).
    pub fn allocated_bytes(&self) -> Option<u64> {
        #[cfg(not(target_arch = "wasm32"))]
        {
            self.device
                .generate_allocator_report()
                .map(|r| r.total_reserved_bytes)
        }
        #[cfg(target_arch = "wasm32")]
        {
            None
        }
    }

    /// Finds an adapter (high performance preferred) and opens a device with the
    /// adapter's own limits and the optional features we can use.
    pub async fn new() -> Result<Self, GpuError> {
        #[cfg(not(target_arch = "wasm32"))]
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        #[cfg(target_arch = "wasm32")]
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends: wgpu::Backends::BROWSER_WEBGPU,
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        });
        let adapter = instance
            .request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                ..Default::default()
            })
            .await
            .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let wanted = wgpu::Features::SHADER_FLOAT32_ATOMIC
            | wgpu::Features::SUBGROUP
            | wgpu::Features::TIMESTAMP_QUERY;
        let features = adapter.features() & wanted;
        let limits = adapter.limits();
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("rogs"),
                required_features: features,
                required_limits: limits.clone(),
                ..Default::default()
            })
            .await
            .map_err(|e| GpuError::RequestDevice(e.to_string()))?;
        let info = adapter.get_info();
        let accumulation = if features.contains(wgpu::Features::SHADER_FLOAT32_ATOMIC) {
            AccumStrategy::NativeF32
        } else {
            AccumStrategy::CasU32
        };
        let report = AdapterReport {
            name: info.name.clone(),
            backend: format!("{:?}", info.backend),
            device_type: format!("{:?}", info.device_type),
            driver: format!("{} {}", info.driver, info.driver_info)
                .trim()
                .to_string(),
            features: features.iter_names().map(|(n, _)| n.to_string()).collect(),
            max_storage_buffer_binding_size: limits.max_storage_buffer_binding_size as u64,
            max_buffer_size: limits.max_buffer_size,
            max_compute_invocations_per_workgroup: limits.max_compute_invocations_per_workgroup,
            max_compute_workgroup_storage_size: limits.max_compute_workgroup_storage_size,
            max_compute_workgroups_per_dimension: limits.max_compute_workgroups_per_dimension,
            subgroups: features.contains(wgpu::Features::SUBGROUP),
            timestamps: features.contains(wgpu::Features::TIMESTAMP_QUERY),
            accumulation,
        };
        let failure = std::sync::Arc::new(std::sync::Mutex::new(None::<String>));
        let record = |slot: &std::sync::Arc<std::sync::Mutex<Option<String>>>, msg: String| {
            if let Ok(mut s) = slot.lock() {
                s.get_or_insert(msg);
            }
        };
        let slot = failure.clone();
        device.on_uncaptured_error(std::sync::Arc::new(move |e: wgpu::Error| {
            let msg = match &e {
                wgpu::Error::OutOfMemory { .. } => {
                    "the GPU ran out of memory; use a coarser grid or a shorter drive".to_string()
                }
                _ => format!("GPU error: {e}"),
            };
            record(&slot, msg);
        }));
        let slot = failure.clone();
        let lost = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flag = lost.clone();
        device.set_device_lost_callback(move |_, why| {
            flag.store(true, std::sync::atomic::Ordering::SeqCst);
            record(
                &slot,
                format!(
                    "the GPU device was lost ({why}); close other GPU-heavy pages or programs and try again"
                ),
            );
        });
        Ok(Self {
            device,
            queue,
            report,
            features,
            limits,
            failure,
            lost,
            pipelines: Default::default(),
            sorter: Default::default(),
            compiled: Default::default(),
        })
    }

    /// The pipeline made for `key`, if any.
    pub(crate) fn cached_pipeline(
        &self,
        key: &(String, String, Vec<String>),
    ) -> Option<wgpu::ComputePipeline> {
        self.pipelines.lock().ok()?.get(key).cloned()
    }

    /// A tiled run starts a tile: natively the pipelines made so far are dropped,
    /// and the next use of each makes it again; in the browser they are kept.
    ///
    /// lavapipe keeps state per pipeline that grows with the dispatches it has run
    /// (about 35 MiB per tile of 24 m at 10 cm, 350 kB a step, on its queue
    /// thread) and frees it only with the pipeline: pipelines kept for the whole
    /// run made resident memory grow with the drive. Remaking them costs a few ms
    /// a tile natively; the page, where SwiftShader takes seconds to compile them,
    /// keeps them.
    pub fn start_tile(&self) {
        #[cfg(not(target_arch = "wasm32"))]
        {
            if let Ok(mut c) = self.pipelines.lock() {
                c.clear();
            }
            if let Ok(mut s) = self.sorter.lock() {
                *s = None;
            }
        }
    }

    /// Compute pipelines compiled on this device so far: a run's set-up on a
    /// device warmed for it (`optim::train::warm_up`) adds none.
    pub fn pipelines_compiled(&self) -> usize {
        self.compiled.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Counts `n` compiled pipelines.
    pub(crate) fn count_compiled(&self, n: usize) {
        self.compiled
            .fetch_add(n, std::sync::atomic::Ordering::Relaxed);
    }

    /// The radix sorter made on this device, if any.
    pub(crate) fn cached_sorter(&self) -> Option<radix_sort::RadixSorter> {
        self.sorter.lock().ok()?.clone()
    }

    /// Keeps the radix sorter `s`.
    pub(crate) fn cache_sorter(&self, s: &radix_sort::RadixSorter) {
        if let Ok(mut slot) = self.sorter.lock() {
            *slot = Some(s.clone());
        }
    }

    /// Keeps pipeline `p` for `key`.
    pub(crate) fn cache_pipeline(
        &self,
        key: (String, String, Vec<String>),
        p: &wgpu::ComputePipeline,
    ) {
        if let Ok(mut c) = self.pipelines.lock() {
            c.insert(key, p.clone());
        }
    }

    /// True once the device is lost (a driver reset, the browser reclaiming it, or
    /// `lose`): nothing more runs on it; a new context is needed.
    pub fn is_lost(&self) -> bool {
        self.lost.load(std::sync::atomic::Ordering::SeqCst)
    }

    /// Destroys the device as a driver reset would: the fault the tests inject
    /// (`--fault-tile`, the page's `?fault_tile=`). Every later use fails and
    /// `check()` says the device was lost.
    pub fn lose(&self) {
        // Backends report the loss asynchronously (WebGPU's `lost` promise): say it now.
        self.release();
        if let Ok(mut s) = self.failure.lock() {
            s.get_or_insert_with(|| {
                "the GPU device was lost (destroyed); close other GPU-heavy pages or programs and try again"
                    .into()
            });
        }
    }

    /// Destroys the device when its owner is done with it, freeing every buffer made
    /// on it at once. In the browser a dropped buffer is freed only when JavaScript's
    /// garbage collector gets to it; a page that runs many reconstructions calls this
    /// so that each run's GPU memory goes with it (the soak test measures it).
    pub fn release(&self) {
        self.lost.store(true, std::sync::atomic::Ordering::SeqCst);
        self.device.destroy();
    }

    /// The first uncaught GPU error or device loss since the context was made.
    pub fn check(&self) -> Result<(), GpuError> {
        match self.failure.lock().ok().and_then(|s| s.clone()) {
            Some(msg) => Err(GpuError::Failed(msg)),
            None => Ok(()),
        }
    }

    /// Blocking constructor for the CLI and native tests.
    #[cfg(not(target_arch = "wasm32"))]
    pub fn new_blocking() -> Result<Self, GpuError> {
        pollster::block_on(Self::new())
    }

    /// Compiles WGSL made of `parts`, adding the `enable` directives browsers need.
    pub fn shader(&self, label: &str, parts: &[&str]) -> wgpu::ShaderModule {
        let mut src = String::new();
        // naga rejects `enable subgroups;` natively, browsers require it.
        if cfg!(target_arch = "wasm32") && self.report.subgroups {
            src.push_str("enable subgroups;\n");
        }
        for p in parts {
            src.push_str(p);
            src.push('\n');
        }
        self.device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(src.into()),
            })
    }

    /// A 2D dispatch size covering `groups` workgroups within the per-dimension limit.
    pub fn dispatch_2d(&self, groups: u32) -> (u32, u32) {
        let max = self.limits.max_compute_workgroups_per_dimension.max(1);
        let x = groups.clamp(1, max);
        (x, groups.div_ceil(x).max(1))
    }
}
