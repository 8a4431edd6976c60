//! File output that never leaves a half-written file behind: write to a temporary name
//! beside the target, then rename over it (atomic on one file system). And its reading
//! side for folders replaced whole (a bundle): files read through one held folder.

use std::io::Write;
use std::path::{Path, PathBuf};

/// A file that could not be written, naming it and the cause. The cause is part of the
/// message and deliberately not exposed as `source()`, so a chained report (`{:#}`)
/// prints it once.
#[derive(Debug)]
pub struct WriteError {
    pub path: PathBuf,
    pub source: std::io::Error,
}

impl std::fmt::Display for WriteError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "could not write {}: {}",
            self.path.display(),
            self.source
        )
    }
}

impl std::error::Error for WriteError {}

/// Writes `bytes` to `path` atomically: readers see the old file or the whole new one.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    let result = std::fs::File::create(&tmp)
        .and_then(|mut f| f.write_all(bytes).and_then(|()| f.sync_all()))
        .and_then(|()| std::fs::rename(&tmp, path));
    result.map_err(|source| {
        let _ = std::fs::remove_file(&tmp);
        WriteError {
            path: path.to_path_buf(),
            source,
        }
    })
}

/// Encodes an RGBA image as PNG and writes it atomically.
pub fn write_png_atomic(path: &Path, image: &image::RgbaImage) -> Result<(), WriteError> {
    let mut bytes = Vec::new();
    image
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .map_err(|e| WriteError {
            path: path.to_path_buf(),
            source: std::io::Error::other(e),
        })?;
    write_atomic(path, &bytes)
}

/// A folder held open: on Linux every file read through it comes from the folder as it
/// was when opened (its descriptor and `openat`), even when another folder is renamed
/// into its place meanwhile, as the trainer replaces a bundle whole; a bundle's manifest
/// and weights read through one therefore belong together. Elsewhere, by path.
pub struct HeldFolder {
    path: PathBuf,
    #[cfg(target_os = "linux")]
    handle: std::fs::File,
}

impl HeldFolder {
    pub fn open(path: &Path) -> std::io::Result<Self> {
        Ok(Self {
            path: path.to_path_buf(),
            #[cfg(target_os = "linux")]
            handle: std::fs::File::open(path)?,
        })
    }

    /// The path of the file `name` in the folder (for messages).
    pub fn path(&self, name: &str) -> PathBuf {
        self.path.join(name)
    }

    /// The bytes of the file `name` (a plain file name) in the held folder.
    pub fn read(&self, name: &str) -> std::io::Result<Vec<u8>> {
        #[cfg(target_os = "linux")]
        {
            use std::io::Read;
            use std::os::fd::{AsRawFd, FromRawFd};
            let name = std::ffi::CString::new(name)?;
            // SAFETY: a valid descriptor and a NUL-terminated name; the new descriptor is
            // owned by the File made from it.
            let fd = unsafe {
                libc::openat(
                    self.handle.as_raw_fd(),
                    name.as_ptr(),
                    libc::O_RDONLY | libc::O_CLOEXEC,
                )
            };
            if fd < 0 {
                return Err(std::io::Error::last_os_error());
            }
            let mut bytes = Vec::new();
            unsafe { std::fs::File::from_raw_fd(fd) }.read_to_end(&mut bytes)?;
            Ok(bytes)
        }
        #[cfg(not(target_os = "linux"))]
        std::fs::read(self.path.join(name))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(target_os = "linux")]
    #[test]
    fn a_held_folder_reads_the_generation_it_opened_after_a_swap() {
        let dir = tempfile::tempdir().unwrap();
        let (bundle, staging) = (dir.path().join("bundle"), dir.path().join(".bundle.new"));
        for (folder, text) in [(&bundle, "old"), (&staging, "new")] {
            std::fs::create_dir(folder).unwrap();
            std::fs::write(folder.join("manifest.json"), text).unwrap();
        }
        let held = HeldFolder::open(&bundle).unwrap();
        // The writer's swap without renameat2: old aside, new in place.
        std::fs::rename(&bundle, dir.path().join(".bundle.old")).unwrap();
        std::fs::rename(&staging, &bundle).unwrap();
        assert_eq!(held.read("manifest.json").unwrap(), b"old");
        assert_eq!(std::fs::read(bundle.join("manifest.json")).unwrap(), b"new");
        let again = HeldFolder::open(&bundle).unwrap();
        assert_eq!(again.read("manifest.json").unwrap(), b"new");
        assert_eq!(held.path("manifest.json"), bundle.join("manifest.json"));
        assert!(held.read("missing.json").is_err());
    }

    #[test]
    fn writes_and_replaces_whole_files() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.json");
        write_atomic(&path, b"first").unwrap();
        write_atomic(&path, b"second").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"second");
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            1,
            "no temporary left"
        );
    }

    #[test]
    fn a_failed_write_names_the_file_and_keeps_the_old_one() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.json");
        write_atomic(&path, b"old").unwrap();
        // A directory where the temporary file must go makes the write fail, even as root.
        std::fs::create_dir(dir.path().join("a.json.tmp")).unwrap();
        let err = write_atomic(&path, b"new").unwrap_err();
        assert!(err.to_string().contains("a.json"), "{err}");
        assert_eq!(std::fs::read(&path).unwrap(), b"old");
    }
}
