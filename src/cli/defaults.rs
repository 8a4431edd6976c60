//! What the subcommands share: the shipped avatar's paths and how they are found, and a
//! headless render under a progress bar.

use std::path::{Path, PathBuf};

use crate::gpu::GpuContext;

/// Environment variable naming the character file the app shows by default.
pub const CHARACTER_ENV: &str = "UNICA_CHARACTER";
/// The default avatar's source, shipped in the repository (CC0; see its SOURCE.md).
const DEFAULT_CHARACTER: &str = "assets/witch/source/Witch.gltf";
/// The default neural avatar, shipped in the repository.
const DEFAULT_BUNDLE: &str = "assets/witch/bundle";

/// The shipped Witch bundle, beside the working directory or in the source tree.
pub fn default_bundle() -> Option<PathBuf> {
    [
        PathBuf::from(DEFAULT_BUNDLE),
        Path::new(env!("CARGO_MANIFEST_DIR")).join(DEFAULT_BUNDLE),
    ]
    .into_iter()
    .find(|p| p.join("manifest.json").is_file())
}

/// `$UNICA_CHARACTER`, else the shared Witch beside the working directory or beside the
/// source tree; `None` if none of them exists.
pub fn default_character() -> Option<PathBuf> {
    if let Some(path) = std::env::var_os(CHARACTER_ENV) {
        return Some(PathBuf::from(path));
    }
    [
        PathBuf::from(DEFAULT_CHARACTER),
        Path::new(env!("CARGO_MANIFEST_DIR")).join(DEFAULT_CHARACTER),
    ]
    .into_iter()
    .find(|p| p.is_file())
}

/// Runs a headless render job under a progress bar (`what` … frames, time left); the
/// number of frames.
pub(super) fn render_with_bar(
    job: &crate::headless::RenderJob,
    gpu: GpuContext,
    what: &str,
) -> anyhow::Result<usize> {
    let bar = indicatif::ProgressBar::new(0).with_style(
        indicatif::ProgressStyle::with_template(&format!(
            "{what} {{bar:40}} {{pos}}/{{len}} frames, {{eta}} left"
        ))
        .expect("valid template"),
    );
    let frames = crate::headless::render(job, gpu, &|done, total| {
        bar.set_length(total);
        bar.set_position(done);
    })?;
    bar.finish_and_clear();
    Ok(frames)
}
