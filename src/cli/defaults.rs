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

/// The neural avatars shipped with unica: name, bundle folder and teacher (the character
/// it learned from), relative to the repository. The first is the default.
const SHIPPED: [(&str, &str, &str); 2] = [
    ("Witch", DEFAULT_BUNDLE, DEFAULT_CHARACTER),
    (
        "Knight",
        "assets/knight/bundle",
        "assets/knight/source/Knight.glb",
    ),
];

/// `relative` beside the working directory, else in the source tree, where `exists`.
fn shipped_path(relative: &str, exists: impl Fn(&Path) -> bool) -> Option<PathBuf> {
    [
        PathBuf::from(relative),
        Path::new(env!("CARGO_MANIFEST_DIR")).join(relative),
    ]
    .into_iter()
    .find(|p| exists(p))
}

/// The shipped avatars whose bundle and teacher are both present, in menu order.
pub fn shipped_avatars() -> Vec<crate::app::ShippedAvatar> {
    SHIPPED
        .iter()
        .filter_map(|(name, bundle, character)| {
            Some(crate::app::ShippedAvatar {
                name: name.to_string(),
                bundle: shipped_path(bundle, |p| p.join("manifest.json").is_file())?,
                character: shipped_path(character, Path::is_file)?,
            })
        })
        .collect()
}

/// The teacher of `bundle` when it is a shipped avatar's bundle folder.
pub fn shipped_teacher(bundle: &Path) -> Option<PathBuf> {
    let wanted = bundle.canonicalize().ok()?;
    shipped_avatars()
        .into_iter()
        .find(|a| a.bundle.canonicalize().is_ok_and(|b| b == wanted))
        .map(|a| a.character)
}

/// The shipped Witch bundle, beside the working directory or in the source tree.
pub fn default_bundle() -> Option<PathBuf> {
    shipped_path(DEFAULT_BUNDLE, |p| p.join("manifest.json").is_file())
}

/// `$UNICA_CHARACTER`, else the shared Witch beside the working directory or beside the
/// source tree; `None` if none of them exists.
pub fn default_character() -> Option<PathBuf> {
    if let Some(path) = std::env::var_os(CHARACTER_ENV) {
        return Some(PathBuf::from(path));
    }
    shipped_path(DEFAULT_CHARACTER, Path::is_file)
}

/// Runs a headless render job under a progress bar (`what` … frames, time left); the
/// number of frames.
pub(super) fn render_with_bar(
    job: &crate::headless::RenderJob,
    gpu: GpuContext,
    what: &str,
) -> anyhow::Result<usize> {
    let bar = super::progress::bar(
        &format!("{what} {{bar:40}} {{pos}}/{{len}} frames, {{left}}"),
        0,
    );
    let frames = crate::headless::render(job, gpu, &|done, total| {
        bar.set_length(total);
        bar.set_position(done);
    })?;
    bar.finish_and_clear();
    Ok(frames)
}
