#[cfg(not(target_arch = "wasm32"))]
fn main() -> std::process::ExitCode {
    rogs::cli::run()
}

#[cfg(target_arch = "wasm32")]
fn main() {}
