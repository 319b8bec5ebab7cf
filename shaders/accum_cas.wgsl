//! Gradient accumulation by compare-and-swap on the f32 bit pattern.
//!
//! WebGPU has no float atomics, so browsers take this path: load the current bits,
//! add in f32, try to swap, and retry with the value another invocation wrote. Under
//! heavy contention this is ~3x slower than a native add (measured on lavapipe), so
//! kernels reduce within the workgroup first and send one add per surfel.

@group(0) @binding(0) var<storage, read_write> accum: array<atomic<u32>>;

fn accum_add(i: u32, v: f32) {
    var old = atomicLoad(&accum[i]);
    loop {
        let r = atomicCompareExchangeWeak(&accum[i], old, bitcast<u32>(bitcast<f32>(old) + v));
        if r.exchanged {
            break;
        }
        old = r.old_value;
    }
}
