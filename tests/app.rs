//! GUI smoke tests: the real window under an X server (Xvfb is started when DISPLAY is
//! unset), screenshots that must not be blank, scripted keys, and recording from the app.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

/// An X display for one test: the ambient one, or a private Xvfb killed on drop.
struct Display {
    name: String,
    server: Option<Child>,
    /// Xvfb's stdout stays open while it runs: a write to a closed pipe would kill it.
    _report: Option<BufReader<std::process::ChildStdout>>,
}

impl Display {
    /// Uses `DISPLAY` if set; otherwise starts Xvfb, which picks a free display number
    /// and reports it once it accepts connections (`-displayfd`).
    fn open() -> Self {
        if let Ok(name) = std::env::var("DISPLAY") {
            return Self {
                name,
                server: None,
                _report: None,
            };
        }
        let mut server = Command::new("Xvfb")
            .args([
                "-displayfd",
                "1",
                "-screen",
                "0",
                "1280x800x24",
                "-nolisten",
                "tcp",
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("Xvfb runs (Debian package xvfb; .ci/run installs it)");
        let mut line = String::new();
        let mut report = BufReader::new(server.stdout.take().unwrap());
        report.read_line(&mut line).unwrap();
        let number: u32 = line
            .trim()
            .parse()
            .unwrap_or_else(|_| panic!("Xvfb reported no display: '{line}'"));
        Self {
            name: format!(":{number}"),
            server: Some(server),
            _report: Some(report),
        }
    }
}

impl Drop for Display {
    fn drop(&mut self) {
        if let Some(server) = &mut self.server {
            // SIGTERM lets Xvfb remove its lock file and socket.
            let _ = Command::new("kill").arg(server.id().to_string()).status();
            let _ = server.wait();
        }
    }
}

fn witch() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/assets/witch/Witch.gltf")
}

fn unica(display: &Display, args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_unica"));
    cmd.args(args)
        .env("DISPLAY", &display.name)
        .env_remove("WAYLAND_DISPLAY");
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().expect("the unica binary runs")
}

fn check(out: &Output) -> String {
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "unica failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

/// Variance of the luma of a region of an image.
fn luma_variance(image: &image::RgbaImage, x0: u32, y0: u32, w: u32, h: u32) -> f64 {
    let values: Vec<f64> = (y0..y0 + h)
        .flat_map(|y| (x0..x0 + w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let p = image.get_pixel(x, y).0;
            0.299 * p[0] as f64 + 0.587 * p[1] as f64 + 0.114 * p[2] as f64
        })
        .collect();
    let mean = values.iter().sum::<f64>() / values.len() as f64;
    values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len() as f64
}

/// The viewport is the left part of the window below the menu bar (the HUD is on the right).
fn viewport_variance(path: &Path) -> f64 {
    let image = image::open(path)
        .expect("the screenshot is a PNG")
        .to_rgba8();
    let (w, h) = image.dimensions();
    assert!(w >= 640 && h >= 400, "window size {w}x{h}");
    luma_variance(&image, w / 8, h / 8, w / 2, h * 3 / 4)
}

#[test]
fn the_witch_window_screenshot_is_not_blank_and_keys_drive_the_action() {
    let display = Display::open();
    let dir = tempfile::tempdir().unwrap();
    let shot = dir.path().join("witch.png");
    let witch = witch();
    let out = unica(
        &display,
        &[
            "--character",
            witch.to_str().unwrap(),
            "--keys",
            "20I 40W",
            "--screenshot",
            shot.to_str().unwrap(),
            "--exit-after",
            "30",
        ],
        &[],
    );
    let stdout = check(&out);
    assert!(
        stdout.contains("30 frames rendered; action Forward; character Witch"),
        "{stdout}"
    );
    let variance = viewport_variance(&shot);
    eprintln!("witch viewport luma variance: {variance:.1}");
    assert!(
        variance > 100.0,
        "viewport looks blank: variance {variance:.1}"
    );
}

#[test]
fn a_missing_character_shows_the_placeholder() {
    let display = Display::open();
    let dir = tempfile::tempdir().unwrap();
    let shot = dir.path().join("placeholder.png");
    let out = unica(
        &display,
        &[
            "--character",
            "/nonexistent/hero.glb",
            "--screenshot",
            shot.to_str().unwrap(),
            "--exit-after",
            "5",
        ],
        &[],
    );
    let stdout = check(&out);
    assert!(stdout.contains("character placeholder"), "{stdout}");
    let variance = viewport_variance(&shot);
    assert!(
        variance > 20.0,
        "placeholder viewport looks blank: variance {variance:.1}"
    );
}

#[test]
fn recording_from_the_window_writes_frames_and_a_manifest() {
    let display = Display::open();
    let dir = tempfile::tempdir().unwrap();
    let frames = dir.path().join("rec");
    let witch = witch();
    let out = unica(
        &display,
        &[
            "--character",
            witch.to_str().unwrap(),
            "--keys",
            "10D",
            "--record",
            "--record-dir",
            frames.to_str().unwrap(),
            "--exit-after",
            "10",
        ],
        &[],
    );
    let stdout = check(&out);
    assert!(stdout.contains("Recorded"), "{stdout}");
    let manifest: serde_json::Value = serde_json::from_slice(
        &std::fs::read(frames.join("manifest.json")).expect("manifest.json"),
    )
    .unwrap();
    let listed = manifest["frames"].as_array().unwrap();
    assert!(!listed.is_empty());
    assert_eq!(manifest["fps"], 30.0);
    for frame in listed {
        let png = image::open(frames.join(frame["file"].as_str().unwrap()))
            .expect("every listed frame opens");
        assert!(png.width() > 100 && png.height() > 100);
    }
    assert_eq!(listed[0]["action"], "Right");
    let leftovers = std::fs::read_dir(&frames)
        .unwrap()
        .filter(|e| e.as_ref().unwrap().path().extension() == Some("tmp".as_ref()))
        .count();
    assert_eq!(leftovers, 0, "no temporary files left");
}

#[test]
fn the_window_without_any_adapter_fails_in_one_line() {
    let display = Display::open();
    let out = unica(
        &display,
        &["--exit-after", "1"],
        &[
            ("WGPU_BACKEND", "vulkan"),
            ("VK_ICD_FILENAMES", "/nonexistent/icd.json"),
            ("VK_DRIVER_FILES", "/nonexistent/icd.json"),
        ],
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && !err.contains("panicked"), "{err}");
    let ours: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("unica: error:"))
        .collect();
    assert_eq!(ours.len(), 1, "{err}");
    assert!(ours[0].contains("mesa-vulkan-drivers"), "{}", ours[0]);
}
