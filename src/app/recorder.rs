//! The recorder: viewport frames at a fixed rate as numbered PNGs, each written atomically
//! on a background thread, plus manifest.json (frame, time, action, camera, the avatar's
//! world root); when an
//! `ffmpeg` binary is on the PATH, also session.mp4 from the frames.

use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, Receiver, Sender};
use std::thread::JoinHandle;

use crate::action::Action;
use crate::files::{WriteError, write_atomic, write_png_atomic};
use crate::render::OrbitCamera;

/// Default recording rate: the avatar's animation rate.
pub const DEFAULT_FPS: f64 = 30.0;
/// Most frames written for one viewport frame when the app falls behind (one second).
const MAX_CATCH_UP: u64 = 30;
/// What was happening when a frame was taken.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Moment {
    pub action: Action,
    pub camera: OrbitCamera,
    /// The avatar's world root (none for a static view).
    pub root: Option<glam::Vec3>,
}

/// What the manifest says about one frame.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FrameRecord {
    pub index: u64,
    pub file: String,
    pub time_s: f64,
    #[serde(flatten)]
    pub moment: Moment,
}

/// The manifest's closing bytes, overwritten by each frame's record and written again
/// after it.
const MANIFEST_TAIL: &[u8] = b"\n]}\n";

/// Writes numbered frames and the manifest into one folder, synchronously. The manifest
/// gains each frame's record as soon as its PNG is in place (one small write in place
/// of the closing bytes), so after a crash or a kill it lists every finished frame and
/// stays valid JSON.
pub struct FrameWriter {
    dir: PathBuf,
    fps: f64,
    frames: u64,
    manifest: std::fs::File,
    /// Where the closing bytes start.
    end: u64,
}

impl FrameWriter {
    pub fn create(dir: &Path, fps: f64) -> Result<Self, WriteError> {
        let fail = |path: PathBuf| move |source| WriteError { path, source };
        std::fs::create_dir_all(dir).map_err(fail(dir.to_path_buf()))?;
        let path = dir.join("manifest.json");
        let head = format!(
            "{{\"unica_version\": {:?}, \"fps\": {}, \"frames\": [",
            env!("CARGO_PKG_VERSION"),
            serde_json::json!(fps)
        );
        write_atomic(&path, &[head.as_bytes(), MANIFEST_TAIL].concat())?;
        let manifest = std::fs::OpenOptions::new()
            .write(true)
            .open(&path)
            .map_err(fail(path.clone()))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            fps,
            frames: 0,
            manifest,
            end: head.len() as u64,
        })
    }

    pub fn frames_written(&self) -> u64 {
        self.frames
    }

    /// Writes the next frame, then adds it to the manifest.
    pub fn write(&mut self, image: &image::RgbaImage, moment: Moment) -> Result<(), WriteError> {
        use std::io::{Seek, SeekFrom, Write};
        let index = self.frames;
        let file = format!("frame_{index:06}.png");
        write_png_atomic(&self.dir.join(&file), image)?;
        let record = FrameRecord {
            index,
            file,
            time_s: index as f64 / self.fps,
            moment,
        };
        let json = serde_json::to_string(&record).expect("a frame record serialises");
        let separator: &[u8] = if index == 0 { b"\n" } else { b",\n" };
        let bytes = [separator, json.as_bytes(), MANIFEST_TAIL].concat();
        self.manifest
            .seek(SeekFrom::Start(self.end))
            .and_then(|_| self.manifest.write_all(&bytes))
            .map_err(|source| WriteError {
                path: self.dir.join("manifest.json"),
                source,
            })?;
        self.end += (bytes.len() - MANIFEST_TAIL.len()) as u64;
        self.frames += 1;
        Ok(())
    }
}

struct Job {
    image: image::RgbaImage,
    moment: Moment,
    copies: u64,
}

/// A recording in progress: paces frames to the fixed rate and hands them to a writer
/// thread, so the window never waits on the disk.
pub struct SessionRecorder {
    pub dir: PathBuf,
    fps: f64,
    queued: u64,
    jobs: Option<Sender<Job>>,
    errors: Receiver<WriteError>,
    thread: Option<JoinHandle<Result<u64, WriteError>>>,
}

impl SessionRecorder {
    pub fn start(dir: &Path, fps: f64) -> Result<Self, WriteError> {
        let mut writer = FrameWriter::create(dir, fps)?;
        let (jobs, job_rx) = mpsc::channel::<Job>();
        let (err_tx, errors) = mpsc::channel();
        let thread = std::thread::spawn(move || {
            let run = |writer: &mut FrameWriter| -> Result<(), WriteError> {
                for job in job_rx {
                    for _ in 0..job.copies {
                        writer.write(&job.image, job.moment)?;
                    }
                }
                Ok(())
            };
            let result = run(&mut writer);
            if let Err(e) = &result {
                // What was written stays listed; the failing frame itself is not.
                let _ = err_tx.send(WriteError {
                    path: e.path.clone(),
                    source: std::io::Error::new(e.source.kind(), e.source.to_string()),
                });
            }
            result.map(|()| writer.frames_written())
        });
        Ok(Self {
            dir: dir.to_path_buf(),
            fps,
            queued: 0,
            jobs: Some(jobs),
            errors,
            thread: Some(thread),
        })
    }

    /// How many frames are due at `elapsed_s` seconds into the recording (0 when the
    /// viewport runs faster than the recording rate, more than 1 when it fell behind).
    pub fn frames_due(&self, elapsed_s: f64) -> u64 {
        let target = (elapsed_s * self.fps).floor() as u64 + 1;
        target.saturating_sub(self.queued).min(MAX_CATCH_UP)
    }

    /// Queues the current viewport image `copies` times (see [`Self::frames_due`]).
    pub fn push(&mut self, image: image::RgbaImage, moment: Moment, copies: u64) {
        if copies == 0 {
            return;
        }
        self.queued += copies;
        if let Some(jobs) = &self.jobs {
            // A send error means the writer stopped on an error, reported by `poll_error`.
            let _ = jobs.send(Job {
                image,
                moment,
                copies,
            });
        }
    }

    /// The write error that stopped the writer, if any.
    pub fn poll_error(&self) -> Option<WriteError> {
        self.errors.try_recv().ok()
    }

    /// Stops, waits for the queue to drain, and returns the number of frames written.
    pub fn stop(mut self) -> Result<u64, WriteError> {
        self.jobs = None;
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(result)) => result,
            _ => Err(WriteError {
                path: self.dir.clone(),
                source: std::io::Error::other("the recording thread crashed"),
            }),
        }
    }
}

/// A recording dropped without `stop` (the window torn down by a panic, as a lost GPU
/// device makes egui's painter do) still writes every frame it was handed.
impl Drop for SessionRecorder {
    fn drop(&mut self) {
        self.jobs = None;
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// The first `ffmpeg` on the PATH.
pub fn find_ffmpeg() -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|dir| dir.join("ffmpeg"))
        .find(|candidate| candidate.is_file())
}

/// Encodes `dir`'s numbered frames at `fps` into `dir/session.mp4` (H.264, yuv420p, even
/// size) with the `ffmpeg` program; the frames stay. ffmpeg writes `session.mp4.tmp`,
/// renamed when it has finished, so a killed encoding leaves no half video under the name.
pub fn encode_mp4(ffmpeg: &Path, dir: &Path, fps: f64) -> Result<PathBuf, String> {
    let (out, partial) = (dir.join("session.mp4"), dir.join("session.mp4.tmp"));
    let run = std::process::Command::new(ffmpeg)
        .current_dir(dir)
        .args(["-y", "-loglevel", "error", "-framerate", &fps.to_string()])
        .args([
            "-i",
            "frame_%06d.png",
            "-vf",
            "pad=ceil(iw/2)*2:ceil(ih/2)*2",
        ])
        .args(["-c:v", "libx264", "-pix_fmt", "yuv420p", "-f", "mp4"])
        .arg("session.mp4.tmp")
        .output()
        .map_err(|e| format!("{}: {e}", ffmpeg.display()))?;
    if run.status.success() && partial.is_file() {
        std::fs::rename(&partial, &out).map_err(|e| format!("{}: {e}", out.display()))?;
        Ok(out)
    } else {
        let _ = std::fs::remove_file(&partial);
        let stderr = String::from_utf8_lossy(&run.stderr);
        Err(format!("{} failed: {}", ffmpeg.display(), stderr.trim()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mp4_encoding_calls_ffmpeg_on_the_numbered_frames() {
        // A stand-in ffmpeg that records its arguments and writes the output file.
        let dir = tempfile::tempdir().unwrap();
        let fake = dir.path().join("ffmpeg");
        std::fs::write(
            &fake,
            "#!/bin/sh\necho \"$@\" > args.txt\ntouch session.mp4.tmp\n",
        )
        .unwrap();
        std::process::Command::new("chmod")
            .arg("+x")
            .arg(&fake)
            .status()
            .unwrap();
        let out = encode_mp4(&fake, dir.path(), 30.0).unwrap();
        assert_eq!(out, dir.path().join("session.mp4"));
        let args = std::fs::read_to_string(dir.path().join("args.txt")).unwrap();
        assert!(args.contains("-framerate 30 -i frame_%06d.png"), "{args}");
        assert!(args.contains("yuv420p -f mp4 session.mp4.tmp"), "{args}");
        assert!(!dir.path().join("session.mp4.tmp").exists());
        // A failing ffmpeg is reported with its message.
        std::fs::write(&fake, "#!/bin/sh\necho 'no libx264' >&2\nexit 1\n").unwrap();
        let err = encode_mp4(&fake, dir.path(), 30.0).unwrap_err();
        assert!(err.contains("no libx264"), "{err}");
    }

    fn moment(action: Action) -> Moment {
        Moment {
            action,
            camera: OrbitCamera::default(),
            root: Some(glam::Vec3::new(1.0, 2.0, 3.0)),
        }
    }

    fn image(v: u8) -> image::RgbaImage {
        image::RgbaImage::from_pixel(4, 3, image::Rgba([v, 0, 0, 255]))
    }

    #[test]
    fn frames_are_paced_to_the_rate() {
        let dir = tempfile::tempdir().unwrap();
        let mut rec = SessionRecorder::start(dir.path(), 30.0).unwrap();
        assert_eq!(rec.frames_due(0.0), 1);
        rec.push(image(1), moment(Action::Idle), 1);
        assert_eq!(rec.frames_due(0.01), 0, "faster than 30 fps: nothing due");
        assert_eq!(rec.frames_due(0.1), 3, "frames 1, 2 and 3 are due at 0.1 s");
        assert_eq!(rec.frames_due(100.0), MAX_CATCH_UP);
        rec.push(image(2), moment(Action::Forward), 3);
        assert_eq!(rec.stop().unwrap(), 4);
        let manifest: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.path().join("manifest.json")).unwrap())
                .unwrap();
        let frames = manifest["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 4);
        assert_eq!(frames[3]["file"], "frame_000003.png");
        assert_eq!(frames[3]["action"], "Forward");
        assert_eq!(frames[3]["root"], serde_json::json!([1.0, 2.0, 3.0]));
        assert!((frames[3]["time_s"].as_f64().unwrap() - 0.1).abs() < 1e-9);
        let png = image::open(dir.path().join("frame_000003.png")).unwrap();
        assert_eq!(png.to_rgba8().get_pixel(0, 0).0, [2, 0, 0, 255]);
    }

    #[test]
    fn a_failing_write_stops_the_recording_and_keeps_earlier_frames() {
        let dir = tempfile::tempdir().unwrap();
        // The temporary name of frame 2 is taken by a directory: that write fails.
        std::fs::create_dir(dir.path().join("frame_000002.png.tmp")).unwrap();
        let mut rec = SessionRecorder::start(dir.path(), 30.0).unwrap();
        rec.push(image(7), moment(Action::Left), 3);
        let err = rec.stop().unwrap_err();
        assert!(err.to_string().contains("frame_000002.png"), "{err}");
        for i in 0..2 {
            let png = image::open(dir.path().join(format!("frame_{i:06}.png"))).unwrap();
            assert_eq!(png.to_rgba8().get_pixel(3, 2).0, [7, 0, 0, 255]);
        }
        let manifest: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.path().join("manifest.json")).unwrap())
                .unwrap();
        assert_eq!(manifest["frames"].as_array().unwrap().len(), 2);
    }

    #[test]
    fn the_manifest_lists_every_frame_as_soon_as_it_is_written() {
        let dir = tempfile::tempdir().unwrap();
        let mut writer = FrameWriter::create(dir.path(), 30.0).unwrap();
        let listed = || {
            let json: serde_json::Value =
                serde_json::from_slice(&std::fs::read(dir.path().join("manifest.json")).unwrap())
                    .unwrap();
            assert_eq!(json["fps"], 30.0);
            json["frames"].as_array().unwrap().len()
        };
        assert_eq!(listed(), 0);
        for n in 1..=3 {
            writer
                .write(&image(n as u8), moment(Action::Right))
                .unwrap();
            // No stop, no drop: what a kill -9 would leave.
            assert_eq!(listed(), n);
        }
    }

    #[test]
    fn an_unusable_folder_is_refused_up_front() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("not_a_folder");
        std::fs::write(&file, b"x").unwrap();
        let err = SessionRecorder::start(&file, 30.0).err().unwrap();
        assert!(err.to_string().contains("not_a_folder"), "{err}");
    }
}
