//! Memory figures for reports: the process's peak resident memory (natively, where
//! the system tells it).

/// Peak resident set size of this process in bytes (Linux: `VmHWM`); `None` where
/// the system does not say (other systems, wasm).
pub fn peak_host_bytes() -> Option<u64> {
    status_bytes("VmHWM:")
}

/// Resident set size of this process now, in bytes (Linux: `VmRSS`).
pub fn host_bytes() -> Option<u64> {
    status_bytes("VmRSS:")
}

/// A `/proc/self/status` memory line in bytes.
fn status_bytes(field: &str) -> Option<u64> {
    #[cfg(target_os = "linux")]
    {
        let s = std::fs::read_to_string("/proc/self/status").ok()?;
        let line = s.lines().find(|l| l.starts_with(field))?;
        let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
        Some(kb * 1024)
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = field;
        None
    }
}

/// Hands the allocator's free pages back to the system (glibc: `malloc_trim`).
///
/// A tiled run allocates and frees a tile's worth of buffers (views, layers,
/// checkpoints) per tile; glibc keeps the freed pages of its main heap mapped, so
/// resident memory crept up by tens of MiB a tile while the live heap stayed flat.
/// Called as each tile finishes, it keeps resident memory near the live heap.
/// Elsewhere (other systems, wasm) it does nothing.
pub fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        extern "C" {
            fn malloc_trim(pad: usize) -> std::ffi::c_int;
        }
        // SAFETY: `malloc_trim` only returns free pages of glibc's own arenas to the
        // kernel; it takes no pointers and is safe to call from any thread.
        unsafe {
            malloc_trim(0);
        }
    }
}
