//! The error of a character file (or of a file beside it) that could not be used.

use std::path::{Path, PathBuf};

/// A character file that could not be used, and why.
#[derive(Debug, thiserror::Error)]
#[error("{}: {problem}", path.display())]
pub struct CharacterError {
    pub path: PathBuf,
    pub problem: String,
}

pub(crate) fn fail(path: &Path, problem: impl Into<String>) -> CharacterError {
    CharacterError {
        path: path.to_path_buf(),
        problem: problem.into(),
    }
}
