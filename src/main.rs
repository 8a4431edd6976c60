//! The `unica` binary: parses the command line and reports any failure in one line.
//! Logging goes through RUST_LOG (driver-level wgpu_hal messages are off by default).

use std::process::ExitCode;

fn main() -> ExitCode {
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
