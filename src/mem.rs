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
