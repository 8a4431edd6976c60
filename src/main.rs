//! The `unica` binary: parses the command line and reports any failure in one line.
//! Logging goes through RUST_LOG (driver-level wgpu_hal messages are off by default).

use std::process::ExitCode;

fn main() -> ExitCode {
    // Without a Wayland session, libwayland-client (probed by the Vulkan loader and
    // winit) prints "error: XDG_RUNTIME_DIR is invalid or not set" on every start when
    // that variable is unset. There is no Wayland display to find then, so point it at
    // the temp folder: the probe fails quietly and X11 or headless use is unchanged.
    if std::env::var_os("XDG_RUNTIME_DIR").is_none()
        && std::env::var_os("WAYLAND_DISPLAY").is_none()
    {
        // SAFETY: first thing in main, before any other thread exists.
        unsafe { std::env::set_var("XDG_RUNTIME_DIR", std::env::temp_dir()) };
    }
    die_with_parent();
    env_logger::Builder::from_env(
        env_logger::Env::default().default_filter_or("warn,wgpu_hal=off"),
    )
    .init();
    match unica::cli::run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let cause = format!("{e:#}").replace('\n', " ");
            eprintln!("unica: error: {cause}");
            ExitCode::FAILURE
        }
    }
}

/// Under `unica make` (UNICA_DIE_WITH_PARENT=its pid in the environment, as the
/// trainers it starts honor too), this process dies with the one that started it, so a
/// make killed with SIGKILL leaves no stage (`unica eval`) running while the same make
/// runs again.
fn die_with_parent() {
    let Some(parent) = std::env::var("UNICA_DIE_WITH_PARENT")
        .ok()
        .and_then(|v| v.parse::<i64>().ok())
    else {
        return;
    };
    #[cfg(target_os = "linux")]
    // SAFETY: prctl with PR_SET_PDEATHSIG takes a signal number and nothing else;
    // getppid has no preconditions.
    unsafe {
        libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL);
        // Taken in by init: the parent died before the request (unless the parent is
        // init itself, a make as a container's entry point).
        if libc::getppid() == 1 && parent != 1 {
            std::process::exit(1);
        }
    }
}
