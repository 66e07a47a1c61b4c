//! Why a store cannot be opened, read or written, and the exit code each cause
//! means.

use std::path::{Path, PathBuf};

use rusqlite::ErrorCode;

use crate::FORMAT_VERSION;

/// Why a store cannot be opened, read or written. Every message names the file and
/// says what to do.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StoreError {
    /// No file.
    #[error(
        "{}: no long-term store: the cascade creates it when motion of camera '{camera}' first arrives; check `site.state_dir` and the camera id",
        file.display()
    )]
    NotFound {
        /// The file.
        file: PathBuf,
        /// The camera looked for.
        camera: String,
    },
    /// Not an SQLite file at all.
    #[error(
        "{} is not an isochron store (not an SQLite database: {detail}); move it away, and the cascade starts a new long-term model",
        file.display()
    )]
    NotSqlite {
        /// The file.
        file: PathBuf,
        /// What was found.
        detail: String,
    },
    /// An SQLite database, but not an isochron store.
    #[error(
        "{} is an SQLite database of another application ({detail}), not an isochron store; point to the right file, or move it away",
        file.display()
    )]
    Foreign {
        /// The file.
        file: PathBuf,
        /// What was found.
        detail: String,
    },
    /// An isochron store of another format version.
    #[error(
        "{} is an isochron store of format version {found}, this isochron reads version {FORMAT_VERSION}; {}",
        file.display(),
        if *found < FORMAT_VERSION as i64 {
            format!("convert it, keeping everything it learned, with `isochron store migrate --store {} --camera <id> --config <site.toml>` (the old file is kept beside it as .v{found})", file.display())
        } else {
            "use the isochron version that wrote it, or move the file away to start a new model".to_string()
        }
    )]
    Version {
        /// The file.
        file: PathBuf,
        /// The version found.
        found: i64,
    },
    /// The store of another camera.
    #[error(
        "{} holds the long-term model of camera '{found}', not '{expected}'; every camera has its own store file: check the file name and `site.state_dir`",
        file.display()
    )]
    Camera {
        /// The file.
        file: PathBuf,
        /// Camera expected.
        expected: String,
        /// Camera in the file.
        found: String,
    },
    /// A model for another block grid.
    #[error(
        "{} holds a model for a {found} block grid, but the motion stream now has {expected} blocks; a model cannot be carried across grids: move the file away to start a new model, or restore the motion settings (block_px, analysis size) it was made with",
        file.display()
    )]
    Grid {
        /// The file.
        file: PathBuf,
        /// Grid of the stream.
        expected: String,
        /// Grid in the file.
        found: String,
    },
    /// A model of another isochronal cycle.
    #[error(
        "{} holds a {found} model, but the config says cascade.cycle = \"{expected}\"; set it back, or convert the model, keeping what it learned, with `isochron store migrate --store {} --camera <id> --config <site.toml>`",
        file.display(),
        file.display()
    )]
    Cycle {
        /// The file.
        file: PathBuf,
        /// Cycle of the config.
        expected: String,
        /// Cycle in the file.
        found: String,
    },
    /// Checksums or SQLite's own checks failed.
    #[error(
        "{} is damaged ({detail}); its long-term model cannot be trusted: restore it from a backup, or move it away to start a new model",
        file.display()
    )]
    Damaged {
        /// The file.
        file: PathBuf,
        /// What is wrong.
        detail: String,
    },
    /// A write on a store opened read-only.
    #[error("{}: opened read-only, cannot write", file.display())]
    ReadOnly {
        /// The file.
        file: PathBuf,
    },
    /// The file (or its directory) cannot be written: permissions, a read-only
    /// mount, an immutable file.
    #[error(
        "{} cannot be written ({detail}); the cascade needs to write its store: check the owner and mode of the file and of `site.state_dir` (the services run as the `isochron` user), and that the filesystem is mounted read-write",
        file.display()
    )]
    NotWritable {
        /// The file.
        file: PathBuf,
        /// What SQLite said.
        detail: String,
    },
    /// The operating system or SQLite failed (disk full, permissions, I/O error).
    #[error("{}: {detail}", file.display())]
    Io {
        /// The file.
        file: PathBuf,
        /// What failed.
        detail: String,
    },
}

/// Maps an SQLite error: corruption and "not a database" are damage, the rest I/O.
pub(crate) fn sql_err(path: &Path, e: rusqlite::Error) -> StoreError {
    let file = path.to_path_buf();
    match e.sqlite_error_code() {
        Some(ErrorCode::DatabaseCorrupt) => StoreError::Damaged {
            file,
            detail: format!("SQLite: {e}"),
        },
        Some(ErrorCode::NotADatabase) => StoreError::NotSqlite {
            file,
            detail: format!("SQLite: {e}"),
        },
        Some(ErrorCode::ReadOnly | ErrorCode::PermissionDenied) => StoreError::NotWritable {
            file,
            detail: format!("SQLite: {e}"),
        },
        _ => StoreError::Io {
            file,
            detail: format!("SQLite: {e}"),
        },
    }
}

impl isochron_exit::Classify for StoreError {
    /// Foreign, damaged or mismatched files are permanent (restarting cannot
    /// help); I/O may pass.
    fn exit_code(&self) -> i32 {
        use StoreError as E;
        use isochron_exit::{CONFIG, DATA, UNAVAILABLE};
        match self {
            E::Damaged { .. } | E::NotSqlite { .. } => DATA,
            E::Foreign { .. }
            | E::Version { .. }
            | E::Camera { .. }
            | E::Grid { .. }
            | E::Cycle { .. }
            | E::NotWritable { .. } => CONFIG,
            E::Io { .. } | E::NotFound { .. } | E::ReadOnly { .. } => UNAVAILABLE,
        }
    }
}
