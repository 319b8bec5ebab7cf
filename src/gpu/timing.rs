//! GPU time per kernel from timestamp queries, for benchmarks.
//!
//! While a `PassTimer` is installed on this thread, every compute pass recorded through
//! `buffers::dispatch` (and the radix sort's pass) is bracketed by two timestamp
//! writes, and `collect` adds the measured durations to per-kernel totals, keyed by
//! the label given to `buffers::pipeline`. Nothing changes when no timer is installed
//! or the adapter lacks `TIMESTAMP_QUERY` (browsers without the feature): `pass_writes`
//! then returns `None` and the benchmarks fall back to wall time.
//!
//! Thread-local rather than threaded through every encoder call: the kernels' host glue
//! stays as it is, and the timer only exists inside `rogs bench`.

use super::readback::read_bytes;
use super::{GpuContext, GpuError};
use std::cell::RefCell;
use std::collections::HashMap;
use std::hash::{Hash, Hasher};

/// Timestamp queries per collection (two per pass).
const CAPACITY: u32 = 4096;

struct Active {
    set: wgpu::QuerySet,
    labels: Vec<String>,
}

thread_local! {
    static ACTIVE: RefCell<Option<Active>> = const { RefCell::new(None) };
    static NAMES: RefCell<HashMap<u64, String>> = RefCell::new(HashMap::new());
}

fn key(p: &wgpu::ComputePipeline) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    p.hash(&mut h);
    h.finish()
}

/// Remembers a pipeline's label for the timer (called by `buffers::pipeline`).
pub fn name(p: &wgpu::ComputePipeline, label: &str) {
    NAMES.with(|n| n.borrow_mut().insert(key(p), label.to_string()));
}

/// The query set and first index of the next pass of `p` (begin, end = index + 1),
/// when a timer is installed and has room.
pub fn pass_slot(p: &wgpu::ComputePipeline) -> Option<(wgpu::QuerySet, u32)> {
    // Every dispatch passes here: without a timer, one thread-local read and out.
    if ACTIVE.with(|a| a.borrow().is_none()) {
        return None;
    }
    let label = NAMES.with(|n| n.borrow().get(&key(p)).cloned())?;
    labelled_slot(&label)
}

/// As `pass_slot`, for a pass that runs several pipelines under one `label`.
pub fn labelled_slot(label: &str) -> Option<(wgpu::QuerySet, u32)> {
    ACTIVE.with(|a| {
        let mut a = a.borrow_mut();
        let a = a.as_mut()?;
        let i = 2 * a.labels.len() as u32;
        if i + 2 > CAPACITY {
            return None;
        }
        a.labels.push(label.to_string());
        Some((a.set.clone(), i))
    })
}

/// The descriptor of a compute pass that writes its timestamps to `slot`.
pub fn pass_descriptor(slot: &Option<(wgpu::QuerySet, u32)>) -> wgpu::ComputePassDescriptor<'_> {
    wgpu::ComputePassDescriptor {
        label: None,
        timestamp_writes: slot
            .as_ref()
            .map(|(set, i)| wgpu::ComputePassTimestampWrites {
                query_set: set,
                beginning_of_pass_write_index: Some(*i),
                end_of_pass_write_index: Some(*i + 1),
            }),
    }
}

/// Per-kernel GPU time, accumulated over the passes recorded while installed.
pub struct PassTimer {
    /// Seconds and passes per kernel label.
    pub totals: HashMap<String, (f64, usize)>,
}

impl PassTimer {
    /// Installs a timer on this thread; `None` when the adapter has no timestamps.
    pub fn install(ctx: &GpuContext) -> Option<Self> {
        if !ctx.features.contains(wgpu::Features::TIMESTAMP_QUERY) {
            return None;
        }
        let set = ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("pass_timer"),
            ty: wgpu::QueryType::Timestamp,
            count: CAPACITY,
        });
        ACTIVE.with(|a| {
            *a.borrow_mut() = Some(Active {
                set,
                labels: Vec::new(),
            })
        });
        Some(Self {
            totals: HashMap::new(),
        })
    }

    /// Resolves the passes recorded (and submitted) since the last call into `totals`.
    pub async fn collect(&mut self, ctx: &GpuContext) -> Result<(), GpuError> {
        let Some((set, labels)) = ACTIVE.with(|a| {
            a.borrow_mut()
                .as_mut()
                .map(|a| (a.set.clone(), std::mem::take(&mut a.labels)))
        }) else {
            return Ok(());
        };
        if labels.is_empty() {
            return Ok(());
        }
        let n = 2 * labels.len() as u32;
        let resolve = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("pass_timer_resolve"),
            size: 8 * n as u64,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        enc.resolve_query_set(&set, 0..n, &resolve, 0);
        ctx.queue.submit([enc.finish()]);
        let raw = read_bytes(ctx, &resolve, 8 * n as u64).await?;
        let ticks: Vec<u64> = bytemuck::pod_collect_to_vec(&raw);
        let period = ctx.queue.get_timestamp_period() as f64 * 1e-9;
        for (k, label) in labels.into_iter().enumerate() {
            let dt = ticks[2 * k + 1].saturating_sub(ticks[2 * k]) as f64 * period;
            let e = self.totals.entry(label).or_insert((0.0, 0));
            e.0 += dt;
            e.1 += 1;
        }
        Ok(())
    }

    /// Seconds over every kernel so far.
    pub fn total(&self) -> f64 {
        self.totals.values().map(|v| v.0).sum()
    }

    /// Kernels by total time, longest first.
    pub fn sorted(&self) -> Vec<(String, f64, usize)> {
        let mut v: Vec<_> = self
            .totals
            .iter()
            .map(|(k, (s, n))| (k.clone(), *s, *n))
            .collect();
        v.sort_by(|a, b| b.1.total_cmp(&a.1));
        v
    }
}

impl Drop for PassTimer {
    fn drop(&mut self) {
        ACTIVE.with(|a| *a.borrow_mut() = None);
    }
}
