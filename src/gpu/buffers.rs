//! Small helpers shared by the host glue of every kernel: buffers, bind groups,
//! pipelines and dispatches. Bindings are given by number because auto layouts hold
//! only the bindings an entry point uses.

use super::GpuContext;

const STORAGE: wgpu::BufferUsages = wgpu::BufferUsages::STORAGE
    .union(wgpu::BufferUsages::COPY_SRC)
    .union(wgpu::BufferUsages::COPY_DST);

/// A zeroed storage buffer (at least 16 bytes: empty bindings are invalid).
pub fn storage(ctx: &GpuContext, label: &str, bytes: u64) -> wgpu::Buffer {
    ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: bytes.max(16).next_multiple_of(4),
        usage: STORAGE,
        mapped_at_creation: false,
    })
}

/// A buffer of `usage` holding `data` (padded with zeros to at least 16 bytes and a
/// multiple of `align`). Written through the queue rather than mapped at creation:
/// on a lost device mapping fails (wgpu's `create_buffer_init` panics then), while a
/// write is refused quietly and the loss is reported by `GpuContext::check`.
fn with_data(
    ctx: &GpuContext,
    label: &str,
    data: &[u8],
    usage: wgpu::BufferUsages,
    align: usize,
) -> wgpu::Buffer {
    let size = data.len().max(16).next_multiple_of(align);
    let buf = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size as u64,
        usage: usage | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    if data.len().is_multiple_of(4) {
        ctx.queue.write_buffer(&buf, 0, data);
    } else {
        let mut bytes = data.to_vec();
        bytes.resize(data.len().next_multiple_of(4), 0);
        ctx.queue.write_buffer(&buf, 0, &bytes);
    }
    buf
}

/// A storage buffer holding `data`.
pub fn init_storage(ctx: &GpuContext, label: &str, data: &[u8]) -> wgpu::Buffer {
    with_data(ctx, label, data, STORAGE, 4)
}

/// A uniform buffer holding `data` (writable later with `queue.write_buffer`).
pub fn uniform(ctx: &GpuContext, label: &str, data: &[u8]) -> wgpu::Buffer {
    with_data(ctx, label, data, wgpu::BufferUsages::UNIFORM, 16)
}

/// A compute pipeline with an automatic layout from WGSL `parts`: made once per
/// device, then the same one (`GpuContext`'s cache, which natively each tile
/// empties: `GpuContext::start_tile`).
pub fn pipeline(
    ctx: &GpuContext,
    label: &str,
    parts: &[&str],
    entry: &str,
) -> wgpu::ComputePipeline {
    let key = (
        label.to_string(),
        entry.to_string(),
        parts.iter().map(|p| p.to_string()).collect(),
    );
    if let Some(p) = ctx.cached_pipeline(&key) {
        return p;
    }
    let module = ctx.shader(label, parts);
    let p = ctx
        .device
        .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(label),
            layout: None,
            module: &module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            cache: None,
        });
    super::timing::name(&p, label);
    ctx.count_compiled(1);
    ctx.cache_pipeline(key, &p);
    p
}

/// A bind group for group 0 of `p` from (binding, buffer) pairs.
pub fn bind(
    ctx: &GpuContext,
    p: &wgpu::ComputePipeline,
    entries: &[(u32, &wgpu::Buffer)],
) -> wgpu::BindGroup {
    let entries: Vec<(u32, wgpu::BufferBinding)> = entries
        .iter()
        .map(|(b, buf)| (*b, buf.as_entire_buffer_binding()))
        .collect();
    bind_ranges(ctx, p, &entries)
}

/// A bind group for group 0 of `p` from (binding, buffer range) pairs.
pub fn bind_ranges(
    ctx: &GpuContext,
    p: &wgpu::ComputePipeline,
    entries: &[(u32, wgpu::BufferBinding)],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = entries
        .iter()
        .map(|(b, range)| wgpu::BindGroupEntry {
            binding: *b,
            resource: wgpu::BindingResource::Buffer(range.clone()),
        })
        .collect();
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &p.get_bind_group_layout(0),
        entries: &entries,
    })
}

/// `bytes` bytes of `buf` from byte `offset` (a multiple of the adapter's storage
/// offset alignment), for a kernel that sees one window of a large buffer.
pub fn window(buf: &wgpu::Buffer, offset: u64, bytes: u64) -> wgpu::BufferBinding<'_> {
    wgpu::BufferBinding {
        buffer: buf,
        offset,
        size: std::num::NonZeroU64::new(bytes),
    }
}

/// Records one compute pass with one dispatch.
pub fn dispatch(
    enc: &mut wgpu::CommandEncoder,
    p: &wgpu::ComputePipeline,
    bg: &wgpu::BindGroup,
    groups: (u32, u32, u32),
) {
    let slot = super::timing::pass_slot(p);
    let mut pass = enc.begin_compute_pass(&super::timing::pass_descriptor(&slot));
    pass.set_pipeline(p);
    pass.set_bind_group(0, bg, &[]);
    pass.dispatch_workgroups(groups.0, groups.1, groups.2);
}

/// Raw bytes of a slice of plain values.
pub fn bytes_of<T: bytemuck::Pod>(v: &[T]) -> &[u8] {
    bytemuck::cast_slice(v)
}
