//! Data parallelism without a thread-pool dependency: scoped threads natively, a plain
//! loop in wasm (where threads need cross-origin isolation). Results never depend on
//! the thread count, so bundles are identical for a seed everywhere.

/// Calls `f(index, item)` for every item, in parallel natively.
pub fn par_chunks<T: Send, F: Fn(usize, &mut T) + Sync>(items: &mut [T], f: F) {
    #[cfg(not(target_arch = "wasm32"))]
    {
        let threads = std::thread::available_parallelism()
            .map_or(1, |n| n.get())
            .min(items.len().max(1));
        let per = items.len().div_ceil(threads.max(1)).max(1);
        std::thread::scope(|scope| {
            for (c, chunk) in items.chunks_mut(per).enumerate() {
                let f = &f;
                scope.spawn(move || {
                    for (k, item) in chunk.iter_mut().enumerate() {
                        f(c * per + k, item);
                    }
                });
            }
        });
    }
    #[cfg(target_arch = "wasm32")]
    for (k, item) in items.iter_mut().enumerate() {
        f(k, item);
    }
}

/// Maps every index in `0..n` through `f`, in parallel natively, preserving order.
pub fn par_map<R: Send + Default, F: Fn(usize) -> R + Sync>(n: usize, f: F) -> Vec<R> {
    let mut out: Vec<R> = (0..n).map(|_| R::default()).collect();
    par_chunks(&mut out, |i, slot| *slot = f(i));
    out
}
