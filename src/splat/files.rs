//! Splat files by format: the reader picked by extension (`.splat`: antimatter15's
//! format; anything else: PLY, whose reader also takes SuperSplat's compressed layout)
//! and the writers (`unica export ply|splat`), with the up-axis conversion of Z-up
//! files to and from unica's Y-up frame.

use std::path::Path;

use glam::Quat;

use super::dotsplat;
use super::ply::{self, PlyError, Splat};

/// Which axis of a splat file points up.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Up {
    /// Y up, as unica draws (no change).
    #[default]
    Y,
    /// Z up: read with a −90° turn about X, (x, y, z) → (x, z, −y), so +Z becomes +Y;
    /// written with the inverse.
    Z,
}

impl Up {
    /// The rotation from the file's frame to unica's.
    pub fn to_y_up(self) -> Quat {
        match self {
            Up::Y => Quat::IDENTITY,
            Up::Z => Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2),
        }
    }
}

/// The splat file formats unica writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// The 3DGS PLY ([`ply`]).
    Ply,
    /// antimatter15's `.splat` ([`dotsplat`]).
    Splat,
}

/// Turns every splat (position and orientation) by `rotation`.
pub fn rotate(splats: &mut [Splat], rotation: Quat) {
    if rotation == Quat::IDENTITY {
        return;
    }
    for s in splats {
        s.position = rotation * s.position;
        s.rotation = (rotation * s.rotation).normalize();
    }
}

/// Whether `path` names a `.splat` file.
pub fn is_dot_splat(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("splat"))
}

/// Splats larger than this (metres, along any axis) are dropped on reading: no scene
/// unica or a 3DGS trainer makes has one, and one such splat covers the whole view (a
/// PLY with log-scales of 80, scales of 5e34 m, drew an empty scene with no word why).
pub const MAX_SCALE: f32 = 1_000.0;
/// Splats farther than this from the origin (metres) are dropped on reading.
pub const MAX_DISTANCE: f32 = 100_000.0;

/// The splats a reading kept, and how many it dropped for absurd values.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Kept {
    pub splats: Vec<Splat>,
    /// Splats larger than [`MAX_SCALE`].
    pub too_large: usize,
    /// Splats farther than [`MAX_DISTANCE`].
    pub too_far: usize,
}

impl Kept {
    /// Keeps the splats within [`MAX_SCALE`] and [`MAX_DISTANCE`], counting the others.
    pub fn sane(splats: Vec<Splat>) -> Self {
        let mut kept = Self::default();
        for s in splats {
            if s.scale.max_element() > MAX_SCALE {
                kept.too_large += 1;
            } else if s.position.length() > MAX_DISTANCE {
                kept.too_far += 1;
            } else {
                kept.splats.push(s);
            }
        }
        kept
    }

    /// The splats dropped.
    pub fn dropped(&self) -> usize {
        self.too_large + self.too_far
    }

    /// One line saying what was dropped and why (None when nothing was).
    pub fn note(&self) -> Option<String> {
        (self.dropped() > 0).then(|| {
            format!(
                "dropped {} of {} splats: {}",
                self.dropped(),
                self.dropped() + self.splats.len(),
                self.why()
            )
        })
    }

    /// Why the dropped splats were dropped: how many for each bound.
    fn why(&self) -> String {
        format!(
            "{} larger than {MAX_SCALE} m, {} farther than {} km from the origin",
            self.too_large,
            self.too_far,
            MAX_DISTANCE / 1000.0
        )
    }
}

/// The splats of a file in unica's Y-up frame (the file's up axis is `up`), without the
/// absurd ones ([`Kept::sane`]). A file whose every splat is absurd is an error that says
/// why.
pub fn read(path: &Path, up: Up) -> Result<Kept, PlyError> {
    let splats = if is_dot_splat(path) {
        dotsplat::read(path)?
    } else {
        ply::read(path)?
    };
    let mut kept = Kept::sane(splats);
    if kept.splats.is_empty() && kept.dropped() > 0 {
        return Err(PlyError {
            path: path.to_path_buf(),
            problem: format!(
                "every one of its {} splats is absurd: {}",
                kept.dropped(),
                kept.why()
            ),
        });
    }
    rotate(&mut kept.splats, up.to_y_up());
    Ok(kept)
}

/// Writes Y-up `splats` as a `format` file whose up axis is `up`.
pub fn write(
    path: &Path,
    splats: &[Splat],
    format: Format,
    up: Up,
) -> Result<(), crate::files::WriteError> {
    let mut turned = splats.to_vec();
    rotate(&mut turned, up.to_y_up().inverse());
    match format {
        Format::Ply => ply::write(path, &turned),
        Format::Splat => dotsplat::write(path, &turned),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// A splat 2 m up +Z, long (0.5) along its Z axis and unrotated.
    fn z_up_splat() -> Splat {
        Splat {
            position: Vec3::new(0.3, 0.0, 2.0),
            f_dc: Vec3::new(0.1, 0.2, 0.3),
            opacity: 0.8,
            scale: Vec3::new(0.01, 0.02, 0.5),
            rotation: Quat::IDENTITY,
        }
    }

    /// The world direction of a splat's longest axis.
    fn long_axis(s: &Splat) -> Vec3 {
        let axes = [Vec3::X, Vec3::Y, Vec3::Z];
        let k = (0..3)
            .max_by(|&a, &b| s.scale[a].total_cmp(&s.scale[b]))
            .unwrap();
        s.rotation * axes[k]
    }

    #[test]
    fn a_z_up_file_stands_up_along_y() {
        let mut splats = vec![z_up_splat()];
        rotate(&mut splats, Up::Z.to_y_up());
        // (x, y, z) → (x, z, −y): (0.3, 0, 2) → (0.3, 2, 0).
        assert!(splats[0].position.distance(Vec3::new(0.3, 2.0, 0.0)) < 1e-6);
        assert!(long_axis(&splats[0]).distance(Vec3::Y) < 1e-6);
        // And +Y of the file goes to −Z.
        assert!((Up::Z.to_y_up() * Vec3::Y).distance(Vec3::NEG_Z) < 1e-6);
        assert_eq!(Up::Y.to_y_up(), Quat::IDENTITY);
    }

    #[test]
    fn export_with_z_up_then_read_with_z_up_round_trips() {
        let dir = tempfile::tempdir().unwrap();
        // Y-up splats as unica holds them: standing at +Y, long along Y.
        let mut standing = vec![z_up_splat()];
        rotate(&mut standing, Up::Z.to_y_up());
        for (format, name) in [(Format::Ply, "s.ply"), (Format::Splat, "s.splat")] {
            let path = dir.path().join(name);
            write(&path, &standing, format, Up::Z).unwrap();
            // In the file, Z is up again.
            let raw = read(&path, Up::Y).unwrap().splats;
            assert!(raw[0].position.distance(Vec3::new(0.3, 0.0, 2.0)) < 1e-6);
            assert!(long_axis(&raw[0]).distance(Vec3::Z) < 1e-2, "{name}");
            let back = read(&path, Up::Z).unwrap().splats;
            assert!(back[0].position.distance(standing[0].position) < 1e-6);
            assert!(long_axis(&back[0]).distance(Vec3::Y) < 1e-2, "{name}");
            // The .splat's 8-bit rotation is within 1/64 rad; the PLY's exact.
            assert!(back[0].rotation.dot(standing[0].rotation).abs() > 1.0 - 2e-4);
        }
    }

    #[test]
    fn the_reader_is_picked_by_extension() {
        let dir = tempfile::tempdir().unwrap();
        let splat = dir.path().join("a.SPLAT");
        write(&splat, &[z_up_splat()], Format::Splat, Up::Y).unwrap();
        assert_eq!(std::fs::read(&splat).unwrap().len(), 32);
        assert_eq!(read(&splat, Up::Y).unwrap().splats.len(), 1);
        // The same bytes named .ply are not a PLY file.
        let ply = dir.path().join("a.ply");
        std::fs::copy(&splat, &ply).unwrap();
        let err = read(&ply, Up::Y).unwrap_err().to_string();
        assert!(
            err.contains("a.ply") && err.contains("not a PLY file"),
            "{err}"
        );
    }
}
