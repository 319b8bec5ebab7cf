//! Host side of `shaders/radix_sort.wgsl`: a stable GPU radix sort of (u32 key, u32
//! value) pairs by the low `key_bits` bits of the key, its CPU oracle and a benchmark.
//!
//! `RadixSorter` holds the pipelines (built once per device); `encode` records a whole
//! sort into the caller's command encoder, so the rasteriser can chain it after the
//! kernel that produced the pairs and their count, with no read-back in between. The
//! count is read on the GPU from a storage buffer; the host only gives the capacity
//! (`max_count`) that sizes the dispatches and the scratch buffers.

use super::readback::read_bytes;
use super::{GpuContext, GpuError};

/// Key bits consumed per pass (256 digits).
pub const BITS_PER_PASS: u32 = 8;
/// Keys per workgroup in the count and scatter kernels (16 threads x 512).
const BLOCK: u32 = 8192;
/// Histogram entries per workgroup in the scan kernels.
const SCAN_BLOCK: u32 = 2048;
const RADIX: u32 = 1 << BITS_PER_PASS;
const MAX_PASSES: u32 = 32 / BITS_PER_PASS;

/// Number of passes a sort by `key_bits` bits needs.
pub fn passes(key_bits: u32) -> u32 {
    key_bits.div_ceil(BITS_PER_PASS)
}

/// The key bits the sort orders by.
pub fn key_mask(key_bits: u32) -> u32 {
    if key_bits >= 32 {
        u32::MAX
    } else {
        (1u32 << key_bits) - 1
    }
}

/// CPU oracle: pairs stably sorted by `key & key_mask(key_bits)`; the bits above are
/// ignored for ordering but kept in the output keys, as on the GPU. Pairs up to the
/// shorter of the two slices.
pub fn sort_pairs_cpu(keys: &[u32], values: &[u32], key_bits: u32) -> (Vec<u32>, Vec<u32>) {
    let mask = key_mask(key_bits);
    let mut pairs: Vec<(u32, u32)> = keys.iter().copied().zip(values.iter().copied()).collect();
    // `sort_by_key` is a stable merge sort.
    pairs.sort_by_key(|&(k, _)| k & mask);
    pairs.into_iter().unzip()
}

/// Which buffer pair holds the sorted result after `encode`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SortedIn {
    A,
    B,
}

/// The caller's buffers: the input in the A pair, the B pair as the other half of the
/// ping-pong (both overwritten), and `count` holding the element count as its first
/// u32. All need `STORAGE` usage and room for `max_count` u32s.
pub struct SortPairs<'a> {
    pub keys_a: &'a wgpu::Buffer,
    pub values_a: &'a wgpu::Buffer,
    pub keys_b: &'a wgpu::Buffer,
    pub values_b: &'a wgpu::Buffer,
    pub count: &'a wgpu::Buffer,
}

/// Per-block histograms and scan tile sums for sorts of up to `capacity` pairs; keep
/// one per sort site to avoid allocating every frame.
pub struct SortScratch {
    hist: wgpu::Buffer,
    partials: wgpu::Buffer,
    capacity: u32,
}

impl SortScratch {
    pub fn capacity(&self) -> u32 {
        self.capacity
    }
}

/// Pipelines of the five kernels and the per-pass parameter table (cloning shares
/// them: `GpuContext` keeps one per device).
#[derive(Clone)]
pub struct RadixSorter {
    layout: wgpu::BindGroupLayout,
    count: wgpu::ComputePipeline,
    scan_reduce: wgpu::ComputePipeline,
    scan_partials: wgpu::ComputePipeline,
    scan_down: wgpu::ComputePipeline,
    scatter: wgpu::ComputePipeline,
    /// One uniform slot per (pass, bits): the parameters never change, so encoding
    /// several sorts before a submit cannot race on a `write_buffer`.
    params: wgpu::Buffer,
    param_stride: u32,
}

fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: wgpu::BufferSize::new(4),
        },
        count: None,
    }
}

/// The first `bytes` of `buffer`.
fn sized(buffer: &wgpu::Buffer, bytes: u64) -> wgpu::BindingResource<'_> {
    wgpu::BindingResource::Buffer(wgpu::BufferBinding {
        buffer,
        offset: 0,
        size: wgpu::BufferSize::new(bytes),
    })
}

fn param_slot(pass: u32, bits: u32) -> u32 {
    pass * BITS_PER_PASS + (bits - 1)
}

async fn check_scope(scope: wgpu::ErrorScopeGuard) -> Result<(), GpuError> {
    match scope.pop().await {
        Some(e) => Err(GpuError::Validation(e.to_string())),
        None => Ok(()),
    }
}

impl RadixSorter {
    /// Compiles the kernels, once per device (`GpuContext`'s cache); a shader or
    /// pipeline error is returned, not raised.
    pub async fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        if let Some(s) = ctx.cached_sorter() {
            return Ok(s);
        }
        let dev = &ctx.device;
        let scope = dev.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = ctx.shader(
            "radix_sort",
            &[
                super::WORKGROUP_WGSL,
                include_str!("../../shaders/radix_sort.wgsl"),
            ],
        );
        let mut entries: Vec<_> = (0..7u32)
            .map(|b| storage_entry(b, matches!(b, 0 | 1 | 6)))
            .collect();
        entries.push(wgpu::BindGroupLayoutEntry {
            binding: 7,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: true,
                min_binding_size: wgpu::BufferSize::new(16),
            },
            count: None,
        });
        let layout = dev.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("radix_sort"),
            entries: &entries,
        });
        let pipeline_layout = dev.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("radix_sort"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = |entry: &str| {
            ctx.count_compiled(1);
            dev.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let param_stride = ctx.limits.min_uniform_buffer_offset_alignment.max(16);
        let mut table = vec![0u8; (param_stride * MAX_PASSES * BITS_PER_PASS) as usize];
        for pass in 0..MAX_PASSES {
            for bits in 1..=BITS_PER_PASS {
                let at = (param_slot(pass, bits) * param_stride) as usize;
                let slot: [u32; 4] = [pass * BITS_PER_PASS, bits, 0, 0];
                table[at..at + 16].copy_from_slice(bytemuck::cast_slice(&slot));
            }
        }
        let params = super::buffers::uniform(ctx, "radix_sort params", &table);
        let sorter = Self {
            count: pipeline("count"),
            scan_reduce: pipeline("scan_reduce"),
            scan_partials: pipeline("scan_partials"),
            scan_down: pipeline("scan_down"),
            scatter: pipeline("scatter"),
            layout,
            params,
            param_stride,
        };
        check_scope(scope).await?;
        ctx.cache_sorter(&sorter);
        Ok(sorter)
    }

    /// Scratch buffers for sorts of up to `capacity` pairs.
    pub fn scratch(&self, ctx: &GpuContext, capacity: u32) -> SortScratch {
        let blocks = capacity.div_ceil(BLOCK) as u64;
        let hist_len = RADIX as u64 * blocks;
        let tiles = hist_len.div_ceil(SCAN_BLOCK as u64);
        let buffer = |label, len: u64| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: 4 * len.max(1),
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            })
        };
        SortScratch {
            hist: buffer("radix_sort hist", hist_len),
            partials: buffer("radix_sort partials", tiles),
            capacity,
        }
    }

    /// Records a sort of the first `count` pairs of the A buffers (count read on the
    /// GPU, clamped to `max_count`) by the low `key_bits` bits of the keys. Returns
    /// the pair that holds the result: A after an even number of passes, B after an
    /// odd one. Only the first `count` entries of the result are meaningful.
    pub fn encode(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        pairs: &SortPairs<'_>,
        scratch: &SortScratch,
        max_count: u32,
        key_bits: u32,
    ) -> Result<SortedIn, GpuError> {
        let invalid = |m: String| Err(GpuError::Validation(format!("radix_sort: {m}")));
        if key_bits > 32 {
            return invalid(format!("key_bits {key_bits} > 32"));
        }
        if max_count > scratch.capacity {
            return invalid(format!(
                "max_count {max_count} exceeds the scratch capacity {}",
                scratch.capacity
            ));
        }
        let bytes = 4 * max_count as u64;
        if bytes > ctx.limits.max_storage_buffer_binding_size {
            return invalid(format!(
                "{max_count} pairs exceed the adapter's storage binding limit"
            ));
        }
        let named = [
            ("keys_a", pairs.keys_a, bytes),
            ("values_a", pairs.values_a, bytes),
            ("keys_b", pairs.keys_b, bytes),
            ("values_b", pairs.values_b, bytes),
            ("count", pairs.count, 4),
        ];
        for (name, buf, need) in named {
            if buf.size() < need || !buf.usage().contains(wgpu::BufferUsages::STORAGE) {
                return invalid(format!("{name} needs STORAGE usage and {need} bytes"));
            }
        }
        let passes = passes(key_bits);
        if passes == 0 || max_count == 0 {
            return Ok(SortedIn::A);
        }
        // Keys and values are bound with exactly the capacity, so that `arrayLength`
        // in the shader clamps a too-large GPU count.
        let bind = |label, [ki, vi, ko, vo]: [&wgpu::Buffer; 4]| {
            let resources = [
                sized(ki, bytes),
                sized(vi, bytes),
                sized(ko, bytes),
                sized(vo, bytes),
                scratch.hist.as_entire_binding(),
                scratch.partials.as_entire_binding(),
                sized(pairs.count, 4),
                sized(&self.params, 16),
            ];
            let entries: Vec<_> = resources
                .into_iter()
                .enumerate()
                .map(|(i, resource)| wgpu::BindGroupEntry {
                    binding: i as u32,
                    resource,
                })
                .collect();
            ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(label),
                layout: &self.layout,
                entries: &entries,
            })
        };
        let (a, b) = (
            [pairs.keys_a, pairs.values_a],
            [pairs.keys_b, pairs.values_b],
        );
        let a_to_b = bind("radix_sort a->b", [a[0], a[1], b[0], b[1]]);
        let b_to_a = bind("radix_sort b->a", [b[0], b[1], a[0], a[1]]);
        let blocks = max_count.div_ceil(BLOCK);
        let (bx, by) = ctx.dispatch_2d(blocks);
        let tiles = (RADIX * blocks).div_ceil(SCAN_BLOCK);
        let (tx, ty) = ctx.dispatch_2d(tiles);
        let slot = super::timing::labelled_slot("radix_sort");
        let mut cpass = encoder.begin_compute_pass(&super::timing::pass_descriptor(&slot));
        for pass in 0..passes {
            let bits = (key_bits - pass * BITS_PER_PASS).min(BITS_PER_PASS);
            let offset = param_slot(pass, bits) * self.param_stride;
            let group = if pass.is_multiple_of(2) {
                &a_to_b
            } else {
                &b_to_a
            };
            cpass.set_bind_group(0, group, &[offset]);
            // Each dispatch sees the previous one's writes (WebGPU orders dispatches).
            cpass.set_pipeline(&self.count);
            cpass.dispatch_workgroups(bx, by, 1);
            cpass.set_pipeline(&self.scan_reduce);
            cpass.dispatch_workgroups(tx, ty, 1);
            cpass.set_pipeline(&self.scan_partials);
            cpass.dispatch_workgroups(1, 1, 1);
            cpass.set_pipeline(&self.scan_down);
            cpass.dispatch_workgroups(tx, ty, 1);
            cpass.set_pipeline(&self.scatter);
            cpass.dispatch_workgroups(bx, by, 1);
        }
        Ok(if passes.is_multiple_of(2) {
            SortedIn::A
        } else {
            SortedIn::B
        })
    }

    /// Uploads, sorts and reads back: for tests and one-off use.
    pub async fn sort(
        &self,
        ctx: &GpuContext,
        keys: &[u32],
        values: &[u32],
        key_bits: u32,
    ) -> Result<(Vec<u32>, Vec<u32>), GpuError> {
        if keys.len() != values.len() {
            return Err(GpuError::Validation(format!(
                "radix_sort: {} keys but {} values",
                keys.len(),
                values.len()
            )));
        }
        if key_bits > 32 {
            return Err(GpuError::Validation(format!(
                "radix_sort: key_bits {key_bits} > 32"
            )));
        }
        if keys.is_empty() {
            return Ok((Vec::new(), Vec::new()));
        }
        let n = u32::try_from(keys.len())
            .map_err(|_| GpuError::Validation("radix_sort: more than 2^32 pairs".into()))?;
        let bufs = SortBuffers::new(ctx, keys, values);
        let scratch = self.scratch(ctx, n);
        let scope = ctx.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        let sorted = self.encode(ctx, &mut enc, &bufs.pairs(), &scratch, n, key_bits);
        ctx.queue.submit([enc.finish()]);
        check_scope(scope).await?;
        let (k, v) = match sorted? {
            SortedIn::A => (&bufs.keys[0], &bufs.values[0]),
            SortedIn::B => (&bufs.keys[1], &bufs.values[1]),
        };
        let k = read_bytes(ctx, k, 4 * n as u64).await?;
        let v = read_bytes(ctx, v, 4 * n as u64).await?;
        Ok((
            bytemuck::pod_collect_to_vec(&k),
            bytemuck::pod_collect_to_vec(&v),
        ))
    }
}

/// Two key/value pairs of buffers plus a count buffer, filled from host slices.
struct SortBuffers {
    keys: [wgpu::Buffer; 2],
    values: [wgpu::Buffer; 2],
    count: wgpu::Buffer,
}

impl SortBuffers {
    /// `keys` and `values` must be non-empty, of equal length below 2^32.
    fn new(ctx: &GpuContext, keys: &[u32], values: &[u32]) -> Self {
        let usage = wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST;
        let init = |label, data: &[u32]| {
            super::buffers::init_storage(ctx, label, bytemuck::cast_slice(data))
        };
        let empty = |label| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: 4 * keys.len() as u64,
                usage,
                mapped_at_creation: false,
            })
        };
        SortBuffers {
            keys: [init("keys_a", keys), empty("keys_b")],
            values: [init("values_a", values), empty("values_b")],
            count: init("count", &[keys.len() as u32]),
        }
    }

    fn pairs(&self) -> SortPairs<'_> {
        SortPairs {
            keys_a: &self.keys[0],
            values_a: &self.values[0],
            keys_b: &self.keys[1],
            values_b: &self.values[1],
            count: &self.count,
        }
    }
}

/// Sorts pairs on the GPU by the low `key_bits` bits of the keys (stable; higher key
/// bits are ignored for ordering and kept). Builds the pipelines on every call: keep a
/// `RadixSorter` to sort repeatedly.
pub async fn sort_pairs(
    ctx: &GpuContext,
    keys: &[u32],
    values: &[u32],
    key_bits: u32,
) -> Result<(Vec<u32>, Vec<u32>), GpuError> {
    RadixSorter::new(ctx)
        .await?
        .sort(ctx, keys, values, key_bits)
        .await
}

/// Waits until the queue has finished all submitted work.
async fn wait_idle(ctx: &GpuContext) -> Result<(), GpuError> {
    #[cfg(not(target_arch = "wasm32"))]
    ctx.device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| GpuError::Validation(e.to_string()))?;
    #[cfg(target_arch = "wasm32")]
    {
        let (tx, rx) = futures_channel::oneshot::channel();
        ctx.queue.on_submitted_work_done(move || {
            // Only fails if the waiter was dropped; nothing to tell then.
            let _ = tx.send(());
        });
        rx.await
            .map_err(|_| GpuError::Validation("work-done callback dropped".into()))?;
    }
    Ok(())
}

/// Sort throughput in keys per second for `n` random 32-bit keys with values: the
/// median of 7 timed sorts, each timing only the sort's submission until the queue is
/// idle (upload, the restore of the unsorted input and read-back are outside).
pub async fn bench_sort(ctx: &GpuContext, n: u32) -> Result<f64, GpuError> {
    let n = n.max(1);
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let keys: Vec<u32> = (0..n)
        .map(|_| {
            // xorshift64*: cheap, deterministic, good enough to spread all 32 bits.
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            (state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 32) as u32
        })
        .collect();
    let values: Vec<u32> = (0..n).collect();
    let sorter = RadixSorter::new(ctx).await?;
    let bufs = SortBuffers::new(ctx, &keys, &values);
    // Pristine input, copied over the A pair before every run: sorting already sorted
    // keys would scatter coherently and flatter the figure.
    let source = SortBuffers::new(ctx, &keys, &values);
    let scratch = sorter.scratch(ctx, n);
    let bytes = 4 * n as u64;
    let mut times = Vec::new();
    // One untimed warm-up run, then 7 timed ones.
    for run in 0..8 {
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(&source.keys[0], 0, &bufs.keys[0], 0, bytes);
        enc.copy_buffer_to_buffer(&source.values[0], 0, &bufs.values[0], 0, bytes);
        ctx.queue.submit([enc.finish()]);
        wait_idle(ctx).await?;
        let t0 = web_time::Instant::now();
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        sorter.encode(ctx, &mut enc, &bufs.pairs(), &scratch, n, 32)?;
        ctx.queue.submit([enc.finish()]);
        wait_idle(ctx).await?;
        if run > 0 {
            times.push(t0.elapsed().as_secs_f64());
        }
    }
    times.sort_by(f64::total_cmp);
    Ok(n as f64 / times[times.len() / 2].max(1e-9))
}
