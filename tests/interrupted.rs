//! Interrupted work (issue #51): `unica bake` and `unica export` killed with SIGKILL at
//! several points, then run again with the same command, end with exactly what an
//! uninterrupted run writes, and no temporary is left. The points are drawn from a fixed
//! seed across the uninterrupted run's time, so a failure can be repeated.

mod common;

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

fn command(args: &[&str]) -> Command {
    let mut cmd = common::unica_command(args);
    cmd.stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null());
    cmd
}

/// Runs `args` to the end; how long it took.
fn run(args: &[&str]) -> Duration {
    let start = Instant::now();
    let status = command(args).status().expect("the unica binary runs");
    assert!(status.success(), "unica {args:?} failed");
    start.elapsed()
}

/// Starts `args`, kills it with SIGKILL after `after` (or lets it end first).
fn kill_after(args: &[&str], after: Duration) {
    let mut child = command(args).spawn().expect("the unica binary runs");
    let start = Instant::now();
    while start.elapsed() < after {
        if child.try_wait().unwrap().is_some() {
            return;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().unwrap();
    child.wait().unwrap();
}

/// Fractions in (0.05, 0.95) of a run's time, from a fixed seed (a small LCG).
fn points(seed: u64, n: usize) -> Vec<f64> {
    let mut state = seed;
    (0..n)
        .map(|_| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            0.05 + 0.9 * ((state >> 11) as f64 / (1u64 << 53) as f64)
        })
        .collect()
}

/// Kills `args` (which write into `out`) at several points, runs it again after each, and
/// checks that `out` then equals `reference`, the uninterrupted run's output.
fn check_resumes(args: &[&str], out: &Path, reference: &Path, took: Duration, seed: u64) {
    let want = common::files(reference);
    for fraction in points(seed, 3) {
        kill_after(args, took.mul_f64(fraction));
        run(args);
        let got = common::files(out);
        let names = |files: &[(std::path::PathBuf, Vec<u8>)]| {
            files.iter().map(|(p, _)| p.clone()).collect::<Vec<_>>()
        };
        assert_eq!(
            names(&got),
            names(&want),
            "killed at {fraction:.2} of the run"
        );
        assert!(
            got == want,
            "killed at {fraction:.2} of the run and run again, the files differ from an uninterrupted run's"
        );
    }
}

#[test]
fn a_bake_killed_part_way_and_run_again_writes_the_same_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let reference = dir.path().join("reference");
    let witch = common::witch();
    let args = |out: &Path| {
        vec![
            "bake".to_string(),
            witch.display().to_string(),
            "--quick".to_string(),
            "--out".to_string(),
            out.display().to_string(),
        ]
    };
    let reference_args = args(&reference);
    let took = run(&reference_args
        .iter()
        .map(String::as_str)
        .collect::<Vec<_>>());
    let out = dir.path().join("killed");
    let killed_args = args(&out);
    let killed: Vec<&str> = killed_args.iter().map(String::as_str).collect();
    check_resumes(&killed, &out, &reference, took, 51);
}

#[test]
fn an_export_killed_part_way_and_run_again_writes_the_same_file() {
    let dir = tempfile::tempdir().unwrap();
    let args = |file: &Path| {
        vec![
            "export".to_string(),
            "splat".to_string(),
            "--bundle".to_string(),
            "assets/witch/bundle".to_string(),
            "--splat-level".to_string(),
            "128".to_string(),
            "--out".to_string(),
            file.display().to_string(),
        ]
    };
    let reference = dir.path().join("reference");
    std::fs::create_dir(&reference).unwrap();
    let reference_args = args(&reference.join("witch.splat"));
    let took = run(&reference_args
        .iter()
        .map(String::as_str)
        .collect::<Vec<_>>());
    let out = dir.path().join("killed");
    std::fs::create_dir(&out).unwrap();
    let killed_args = args(&out.join("witch.splat"));
    let killed: Vec<&str> = killed_args.iter().map(String::as_str).collect();
    check_resumes(&killed, &out, &reference, took, 52);
}
