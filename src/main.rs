#[cfg(not(target_arch = "wasm32"))]
fn main() -> std::process::ExitCode {
    // Warnings and errors of rogs and wgpu by default; RUST_LOG=info (or
    // RUST_LOG=wgpu_hal=debug, …) for more.
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    runtime_dir();
    rogs::cli::run()
}

/// Mesa's Vulkan loader complains on every run when XDG_RUNTIME_DIR is unset or not a
/// directory (containers, CI, cron): point it at a private one, as scripts/env.sh
/// does. Runs first, before any thread exists.
#[cfg(not(target_arch = "wasm32"))]
fn runtime_dir() {
    let ok = std::env::var_os("XDG_RUNTIME_DIR")
        .map(std::path::PathBuf::from)
        .is_some_and(|d| d.is_dir());
    if ok {
        return;
    }
    let user = std::env::var("USER").unwrap_or_else(|_| "user".into());
    let dir = std::env::temp_dir().join(format!("rogs-xdg-{user}"));
    if std::fs::create_dir_all(&dir).is_ok() {
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let _ = std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o700));
        }
        // Called at the start of main, while this process has one thread.
        std::env::set_var("XDG_RUNTIME_DIR", &dir);
    }
}

#[cfg(target_arch = "wasm32")]
fn main() {}
