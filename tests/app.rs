//! GUI smoke tests: the real window under an X server (Xvfb is started when DISPLAY is
//! unset), screenshots that must not be blank, scripted keys, and recording from the app.

mod common;

use common::{shipped_bundle, witch};

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::sync::OnceLock;

/// The X display for the window tests: `DISPLAY` if set, else one Xvfb for this whole
/// test process. (Xvfbs started and stopped side by side race for display numbers and
/// can delete each other's sockets, so the tests share one; `-noreset` keeps it from
/// resetting, and refusing clients, whenever its last client leaves.) A watchdog shell
/// stops the Xvfb when this process exits.
fn display() -> &'static str {
    static DISPLAY: OnceLock<String> = OnceLock::new();
    DISPLAY.get_or_init(|| {
        if let Ok(name) = std::env::var("DISPLAY") {
            return name;
        }
        let watchdog = format!(
            "Xvfb -displayfd 1 -screen 0 1280x800x24 -nolisten tcp -noreset 2>/dev/null & x=$!; \
             while kill -0 {} 2>/dev/null; do sleep 0.5; done; kill $x",
            std::process::id()
        );
        let mut shell = Command::new("sh")
            .args(["-c", &watchdog])
            .stdout(Stdio::piped())
            .spawn()
            .expect("sh runs");
        let mut line = String::new();
        let mut report = BufReader::new(shell.stdout.take().unwrap());
        report.read_line(&mut line).unwrap();
        // The watchdog outlives every test. A thread keeps Xvfb's stdout open (a write
        // to a closed pipe would kill it) and reaps the shell should it end early.
        std::thread::spawn(move || {
            let _report = report;
            shell.wait()
        });
        let number: u32 = line.trim().parse().unwrap_or_else(|_| {
            panic!("Xvfb did not start (Debian package xvfb; .ci/run installs it): '{line}'")
        });
        format!(":{number}")
    })
}

fn unica(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_unica"));
    cmd.args(args)
        .env("DISPLAY", display())
        .env_remove("WAYLAND_DISPLAY");
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().expect("the unica binary runs")
}

/// The luma variance of `shot`'s viewport, after checking that `what` covers over 2 % of
/// it.
fn assert_covers(shot: &Path, what: &str) -> f64 {
    let (variance, covered) = viewport_stats(shot);
    eprintln!(
        "{what}: luma variance {variance:.1}, {:.1}% of the viewport covered",
        covered * 100.0
    );
    assert!(
        covered > 0.02,
        "{what} cover only {:.2}% of the viewport",
        covered * 100.0
    );
    variance
}

/// The runs of the neural avatar take turns: two at once on a 2-core machine halve each
/// model's share, and the pacing the neural test measures is then the other run's.
static MODEL_RUNS: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// The window on a shipped bundle, driven by the key script `keys` for `seconds`, with
/// a screenshot to `shot` and `extra` arguments: its stdout, after checking it succeeded.
fn play(name: &str, keys: &str, shot: &Path, seconds: u32, extra: &[&str]) -> String {
    let screenshot = ["--screenshot", shot.to_str().unwrap()];
    let out = drive(name, keys, seconds, &[&screenshot[..], extra].concat(), &[]);
    if extra.contains(&"--stress-resize") {
        check_stressed(&out)
    } else {
        check(&out)
    }
}

/// The window run with `args` for `frames` window frames, then a screenshot to `shot`:
/// its stdout, after checking it succeeded.
fn shoot(args: &[&str], shot: &Path, frames: u32) -> String {
    let frames = frames.to_string();
    let tail = [
        "--screenshot",
        shot.to_str().unwrap(),
        "--exit-after",
        &frames,
    ];
    check(&unica(&[args, &tail[..]].concat(), &[]))
}

/// Fails when a viewport's luma variance says it looks blank (the grid alone stays well
/// below 20).
fn assert_not_blank(variance: f64, what: &str) {
    assert!(
        variance > 20.0,
        "{what}: the viewport looks blank: variance {variance:.1}"
    );
}

/// The window on a shipped bundle, driven by the key script `keys` for `seconds`, with
/// `extra` arguments and environment `env`; the neural runs take turns (`MODEL_RUNS`).
fn drive(name: &str, keys: &str, seconds: u32, extra: &[&str], env: &[(&str, &str)]) -> Output {
    let _turn = MODEL_RUNS.lock().unwrap_or_else(|e| e.into_inner());
    let bundle = shipped_bundle(name);
    let seconds = seconds.to_string();
    let mut args = vec![
        "--bundle",
        bundle.to_str().unwrap(),
        "--keys",
        keys,
        "--exit-after-seconds",
        &seconds,
    ];
    args.extend_from_slice(extra);
    unica(&args, env)
}

/// The arguments of a recording into `rec` at 2 frames a second.
fn record_into(rec: &Path) -> [&str; 5] {
    [
        "--record",
        "--record-fps",
        "2",
        "--record-dir",
        rec.to_str().unwrap(),
    ]
}

/// A run that succeeded without any GPU error (the window reports them and goes on, so
/// the final line's count is where a validation error shows).
fn check(out: &Output) -> String {
    let stdout = check_stressed(out);
    assert!(
        !stdout.contains("gpu_errors=") || stdout.contains("gpu_errors=0"),
        "GPU errors:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

/// A run that succeeded; GPU errors allowed (a window resized faster than lavapipe can
/// reconfigure it reports a few).
fn check_stressed(out: &Output) -> String {
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

/// Luma variance of the viewport (the left part of the window below the menu bar; the
/// HUD is on the right) and the share of its pixels far from the background colour.
/// A blank viewport has variance 0; the grid alone stays well below 20.
fn viewport_stats(path: &Path) -> (f64, f64) {
    let image = image::open(path)
        .expect("the screenshot is a PNG")
        .to_rgba8();
    let (w, h) = image.dimensions();
    assert!(w >= 640 && h >= 400, "window size {w}x{h}");
    let (x0, y0, vw, vh) = (w / 8, h / 8, w / 2, h * 3 / 4);
    let background = image.get_pixel(x0, y0).0;
    let far = (y0..y0 + vh)
        .flat_map(|y| (x0..x0 + vw).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            let p = image.get_pixel(x, y).0;
            (0..3)
                .map(|c| (p[c] as i32 - background[c] as i32).abs())
                .sum::<i32>()
                > 45
        })
        .count();
    (
        luma_variance(&image, x0, y0, vw, vh),
        far as f64 / (vw * vh) as f64,
    )
}

#[test]
fn the_witch_window_screenshot_is_not_blank_and_keys_drive_the_action() {
    let dir = tempfile::tempdir().unwrap();
    let shot = dir.path().join("witch.png");
    let witch = witch();
    let args = ["--character", witch.to_str().unwrap(), "--keys", "20I 40W"];
    let stdout = shoot(&args, &shot, 30);
    assert!(
        stdout.contains("30 frames rendered; action Forward; character Witch"),
        "{stdout}"
    );
    assert_not_blank(assert_covers(&shot, "the witch"), "the witch");
}

#[test]
fn the_neural_witch_is_generated_and_drawn_while_the_window_yields() {
    // The shipped bundle, which plays beside its teacher without --character, at its
    // defaults: the distilled student, one UNet pass a frame. The window draws only when something changes (a
    // new generated frame, the first frame's note each half second), so the model gets
    // the machine; the run ends after 45 s whatever was drawn. The key script counts
    // generated frames, not window frames.
    let dir = tempfile::tempdir().unwrap();
    let shot = dir.path().join("neural.png");
    let record = dir.path().join("rec");
    let extra = [
        "--record",
        "--record-fps",
        "2",
        "--record-dir",
        record.to_str().unwrap(),
    ];
    let stdout = play("witch", "2I 100W 10000D", &shot, 45, &extra);
    let generated: u64 = stdout
        .split("; ")
        .find_map(|part| part.trim_end().strip_suffix(" generated frames"))
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no generated frame count: {stdout}"));
    assert!(generated >= 1, "{stdout}");
    assert!(
        stdout.contains("; teacher Witch beside;"),
        "the shipped bundle plays without its teacher: {stdout}"
    );
    let next = match generated {
        0..2 => "Idle",
        2..102 => "Forward",
        _ => "Right",
    };
    assert!(
        stdout.contains(&format!("action {next};")),
        "after {generated} generated frames the script's next action is {next}: {stdout}"
    );
    let value = |key: &str| -> String {
        stdout
            .split_whitespace()
            .find_map(|w| w.strip_prefix(key))
            .unwrap_or_else(|| panic!("no {key} on the final line: {stdout}"))
            .trim_end_matches(';')
            .to_string()
    };
    let generated_fps: f64 = value("generated_fps=").parse().unwrap();
    let window_fps: f64 = value("window_fps=").parse().unwrap();
    assert_eq!(value("input_latency_ms="), "none", "no input was given");
    // Without input the window draws once per generated frame and nothing else (a
    // window redrawing unchanged pictures ran at 16-20 fps here).
    assert!(
        generated_fps > 0.0 && window_fps <= 2.0 * generated_fps + 1.0,
        "the window drew {window_fps} frames a second for {generated_fps} generated: {stdout}"
    );
    // The camera follows the avatar through its generated frames: every recorded frame
    // after the first generated one knows her root, and the camera's target moved with
    // it (she runs W, then D).
    let manifest: serde_json::Value = serde_json::from_slice(
        &std::fs::read(dir.path().join("rec/manifest.json")).expect("manifest.json"),
    )
    .unwrap();
    let listed = manifest["frames"].as_array().unwrap();
    let (first, last) = (&listed[0], listed.last().unwrap());
    assert!(
        !last["root"].is_null(),
        "the last recorded frame has no root: the camera lost the avatar"
    );
    if generated >= 4 {
        assert_ne!(
            first["camera"]["target"], last["camera"]["target"],
            "the camera stayed while the avatar ran"
        );
    }
    assert_covers(&shot, "the neural witch and her teacher");
}

#[test]
fn the_shipped_knight_plays_beside_its_teacher() {
    // The second shipped avatar, as View → Avatar opens it: its bundle plays beside its
    // teacher, is generated and drawn, and covers part of the viewport.
    let dir = tempfile::tempdir().unwrap();
    let shot = dir.path().join("knight.png");
    let stdout = play("knight", "2I 100W", &shot, 30, &[]);
    assert!(
        stdout.contains("; teacher Knight beside;"),
        "the shipped Knight plays without its teacher: {stdout}"
    );
    assert!(!stdout.contains("; 0 generated frames"), "{stdout}");
    assert_covers(&shot, "the Knight and his teacher");
}

#[test]
fn view_shows_a_3dgs_file_written_by_another_program() {
    // An ASCII PLY in another property order with doubles and extra SH coefficients:
    // a 10 × 10 × 10 grid of grey-blue splats 1 m across.
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("other.ply");
    let mut text = String::from(
        "ply\nformat ascii 1.0\ncomment written by another tool\nelement vertex 1000\n\
         property double x\nproperty double y\nproperty double z\nproperty float f_rest_0\n\
         property float scale_0\nproperty float scale_1\nproperty float scale_2\n\
         property float rot_0\nproperty float rot_1\nproperty float rot_2\nproperty float rot_3\n\
         property float opacity\nproperty float f_dc_0\nproperty float f_dc_1\nproperty float f_dc_2\n\
         end_header\n",
    );
    for i in 0..1000 {
        let (x, y, z) = (
            (i % 10) as f32 * 0.1,
            (i / 10 % 10) as f32 * 0.1 + 0.5,
            (i / 100) as f32 * 0.1,
        );
        text += &format!("{x} {y} {z} 0.3 -3.0 -3.0 -3.0 1 0 0 0 2.0 0.2 0.5 0.9\n");
    }
    std::fs::write(&file, text).unwrap();
    let shot = dir.path().join("view.png");
    let stdout = shoot(&["view", file.to_str().unwrap()], &shot, 5);
    assert!(stdout.contains("(1000 splats)"), "{stdout}");
    assert_covers(&shot, "the splats");
}

#[test]
fn a_missing_character_shows_the_placeholder() {
    let dir = tempfile::tempdir().unwrap();
    let shot = dir.path().join("placeholder.png");
    let stdout = shoot(&["--character", "/nonexistent/hero.glb"], &shot, 5);
    assert!(stdout.contains("character placeholder"), "{stdout}");
    assert_not_blank(viewport_stats(&shot).0, "the placeholder");
}

#[test]
fn recording_from_the_window_writes_frames_and_a_manifest() {
    let dir = tempfile::tempdir().unwrap();
    let frames = dir.path().join("rec");
    let witch = witch();
    let out = unica(
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
fn the_window_survives_200_resizes_down_to_one_pixel_and_hiding_while_it_records() {
    // The neural Witch beside her teacher, the model running and a recording on, while the
    // window goes through 200 sizes from 1280 × 800 to 1 × 1 and back, one a frame, then is
    // minimized and unmapped (a hidden window draws nothing) for a second and shown again.
    // No panic, exit 0, and the recording keeps every frame: as many as its rate and the
    // time say, listed in order in the manifest, each a whole PNG, nothing temporary. GPU
    // errors no scope caught (on lavapipe, a surface reconfigured while the model's thread
    // submits) go to the HUD and the log and are counted in the final line.
    let dir = tempfile::tempdir().unwrap();
    let (shot, rec) = (dir.path().join("resized.png"), dir.path().join("rec"));
    let extra = [&["--stress-resize", "200"][..], &record_into(&rec)].concat();
    let stdout = play("witch", "60W 40A 60D 40S", &shot, 40, &extra);
    let last = stdout.lines().find(|l| l.contains("frames rendered"));
    eprintln!("{last:?}");
    assert!(last.is_some_and(|l| l.contains("gpu_errors=")), "{stdout}");
    // 40 s at 2 a second, the recording starting with the window.
    let recorded = assert_recording_whole(&rec);
    assert!(
        recorded >= 76,
        "{recorded} frames recorded in 40 s at 2 fps"
    );
}

#[test]
fn a_lost_device_ends_the_window_in_one_line_and_keeps_the_recording() {
    // The neural Witch with the model running and a recording on; the GPU device is
    // destroyed (lost) 12 s in. egui's painter panics when it cannot upload to a lost
    // device; the run must still end with exit 1 and one line, no panic shown, and the
    // recording must keep every frame made before the loss, whole and listed.
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec");
    let extra = [&record_into(&rec)[..], &["--stress-lose-device", "12"]].concat();
    let out = drive("witch", "60W 40A 60D 40S", 60, &extra, &[]);
    assert_scripted_failure(&out, "the GPU device was lost");
    let recorded = assert_recording_whole(&rec);
    assert!(
        recorded >= 22,
        "{recorded} frames recorded in the 12 s at 2 fps"
    );
}

#[test]
fn the_window_survives_being_minimized_by_a_window_manager() {
    // The same stress under a real window manager (openbox on its own Xvfb), which
    // iconifies the window when it is minimized: the window must be seen iconified
    // (WM_STATE Iconic), then normal again, and the run must end as any other, its
    // recording whole and as long as its rate and time say.
    let managed = ManagedDisplay::start();
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec");
    let watching = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true));
    let watcher = {
        let (display, watching) = (managed.name.clone(), watching.clone());
        std::thread::spawn(move || {
            let mut states: Vec<String> = Vec::new();
            while watching.load(std::sync::atomic::Ordering::Relaxed) {
                for state in window_states(&display) {
                    if states.last() != Some(&state) {
                        states.push(state);
                    }
                }
                std::thread::sleep(std::time::Duration::from_millis(200));
            }
            states
        })
    };
    let extra = [&["--stress-resize", "20"][..], &record_into(&rec)].concat();
    let out = drive(
        "witch",
        "60W 40A",
        30,
        &extra,
        &[("DISPLAY", &managed.name)],
    );
    watching.store(false, std::sync::atomic::Ordering::Relaxed);
    let states = watcher.join().unwrap();
    check_stressed(&out);
    let iconic = states.iter().position(|s| s == "Iconic");
    assert!(iconic.is_some(), "never iconified: {states:?}");
    assert!(
        states[iconic.unwrap()..].iter().any(|s| s == "Normal"),
        "not shown again: {states:?}"
    );
    let recorded = assert_recording_whole(&rec);
    assert!(
        recorded >= 56,
        "{recorded} frames recorded in 30 s at 2 fps"
    );
}

/// An Xvfb of its own with openbox managing its windows; both stopped when dropped.
struct ManagedDisplay {
    name: String,
    server: std::process::Child,
    manager: std::process::Child,
}

impl ManagedDisplay {
    fn start() -> Self {
        let missing = "needs Xvfb, openbox and xprop (Debian packages xvfb, openbox and \
                       x11-utils; .ci/run installs them)";
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
            .expect(missing);
        let mut line = String::new();
        BufReader::new(server.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let name = format!(":{}", line.trim());
        let manager = Command::new("openbox")
            .arg("--sm-disable")
            .env("DISPLAY", &name)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect(missing);
        // openbox is managing once it has set the root's _NET_SUPPORTING_WM_CHECK.
        let ready = (0..100).any(|_| {
            std::thread::sleep(std::time::Duration::from_millis(100));
            let root = Command::new("xprop")
                .args(["-root", "_NET_SUPPORTING_WM_CHECK"])
                .env("DISPLAY", &name)
                .output()
                .expect(missing);
            String::from_utf8_lossy(&root.stdout).contains("window id")
        });
        assert!(ready, "openbox did not start on {name}");
        Self {
            name,
            server,
            manager,
        }
    }
}

impl Drop for ManagedDisplay {
    fn drop(&mut self) {
        let _ = self.manager.kill();
        let _ = self.server.kill();
        let _ = self.manager.wait();
        let _ = self.server.wait();
    }
}

/// The WM_STATE ("Normal", "Iconic", …) of each window the manager lists on `display`.
fn window_states(display: &str) -> Vec<String> {
    let xprop = |args: &[&str]| {
        let out = Command::new("xprop")
            .args(args)
            .env("DISPLAY", display)
            .output()
            .expect("xprop runs");
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let clients = xprop(&["-root", "_NET_CLIENT_LIST"]);
    clients
        .split([' ', ','])
        .filter(|word| word.starts_with("0x"))
        .filter_map(|id| {
            let state = xprop(&["-id", id, "WM_STATE"]);
            let (_, rest) = state.split_once("window state: ")?;
            Some(rest.split_whitespace().next()?.to_string())
        })
        .collect()
}

/// A recording folder as the recorder leaves it: every frame listed in order in the
/// manifest, each a whole PNG, every PNG listed, nothing temporary. The frame count.
fn assert_recording_whole(rec: &Path) -> usize {
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(rec.join("manifest.json")).unwrap()).unwrap();
    let listed = manifest["frames"].as_array().unwrap();
    for (i, frame) in listed.iter().enumerate() {
        assert_eq!(frame["index"], i as u64, "frames in order, none missing");
        image::open(rec.join(frame["file"].as_str().unwrap())).expect("every frame opens");
    }
    let pngs = std::fs::read_dir(rec)
        .unwrap()
        .filter(|e| e.as_ref().unwrap().path().extension() == Some("png".as_ref()))
        .count();
    assert_eq!(
        pngs,
        listed.len(),
        "every PNG is listed, nothing else is left"
    );
    common::assert_all_whole(rec);
    listed.len()
}

#[test]
fn the_window_without_any_adapter_fails_in_one_line() {
    let out = unica(
        &["--exit-after", "1"],
        &[
            ("WGPU_BACKEND", "vulkan"),
            ("VK_ICD_FILENAMES", "/nonexistent/icd.json"),
            ("VK_DRIVER_FILES", "/nonexistent/icd.json"),
        ],
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    let line = common::error_line(&out);
    assert!(line.contains("mesa-vulkan-drivers"), "{line}");
}

/// A scripted run that fails: exit 1, no panic, one `unica: error:` line with `needle`.
fn assert_scripted_failure(out: &Output, needle: &str) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "should fail: {err}");
    let line = common::error_line(out);
    assert!(line.contains(needle), "expected '{needle}' in {line}");
}

/// The teacher Witch running W for `frames` frames, recorded into `dir`.
fn record_witch(frames: u32, dir: &Path) -> Output {
    let (witch, frames) = (witch(), frames.to_string());
    let keys = format!("{frames}W");
    let args = [
        "--character",
        witch.to_str().unwrap(),
        "--keys",
        &keys,
        "--record",
        "--record-dir",
        dir.to_str().unwrap(),
        "--exit-after",
        &frames,
    ];
    unica(&args, &[])
}

#[test]
fn recording_into_an_unusable_folder_fails_a_scripted_run() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("not_a_folder");
    std::fs::write(&file, b"x").unwrap();
    let out = record_witch(5, &file);
    assert_scripted_failure(&out, "cannot record: could not write");
}

#[test]
fn recording_onto_a_full_disk_fails_a_scripted_run_and_keeps_whole_frames() {
    // A 1280×800 frame is a few hundred KB: a 1 MB tmpfs fills after a few.
    let disk = common::SmallDisk::mount("1m");
    let frames = disk.path.join("rec");
    let out = record_witch(40, &frames);
    assert_scripted_failure(&out, "No space left on device");
    assert!(common::error_line(&out).contains(&disk.path.display().to_string()));
    let files = common::assert_all_whole(&frames);
    assert!(
        files > 1,
        "some frames should be written before the disk fills"
    );
}

#[test]
fn a_bundle_whose_weights_fail_to_load_fails_a_scripted_run() {
    let dir = tempfile::tempdir().unwrap();
    let bundle = dir.path().join("bundle");
    std::fs::create_dir(&bundle).unwrap();
    let manifest = shipped_bundle("witch").join("manifest.json");
    std::fs::copy(manifest, bundle.join("manifest.json")).unwrap();
    std::fs::write(bundle.join("weights.safetensors"), b"not tensors").unwrap();
    let out = unica(
        &["--bundle", bundle.to_str().unwrap(), "--exit-after", "50"],
        &[],
    );
    assert_scripted_failure(&out, "the neural avatar stopped");
}
