//! MCAP recordings: the site's channels into a chunked, LZ4-compressed MCAP file
//! (the `foxglove` crate's writer), closed cleanly — summary and footer written, so
//! it stays readable — when the recording ends, and also when the disk it is on
//! runs low: below [`RESERVE_BYTES`] free, the recorder closes the file while there
//! is still room for the last chunk and the summary, instead of failing mid-write.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use foxglove::{Context, McapCompression, McapWriteOptions, McapWriterHandle};

/// Free space under which a recording is closed, bytes: a few chunks and the
/// summary.
pub const RESERVE_BYTES: u64 = 4 << 20;
/// Uncompressed chunk size, bytes.
const CHUNK_BYTES: u64 = 1 << 20;

/// Why a recording failed.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The file cannot be created.
    #[error("--out {path}: cannot write: {error}")]
    Create {
        /// The file.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// The MCAP writer failed.
    #[error("{path}: {error}")]
    Mcap {
        /// The file.
        path: PathBuf,
        /// Why.
        error: foxglove::FoxgloveError,
    },
}

/// An MCAP file being written.
pub struct Recording {
    handle: McapWriterHandle<BufWriter<File>>,
    path: PathBuf,
}

impl Recording {
    /// Creates (or truncates) `path` and records every channel of `ctx` into it.
    pub fn create(path: &Path, ctx: &Arc<Context>) -> Result<Recording, RecordError> {
        let file = File::create(path).map_err(|error| RecordError::Create {
            path: path.to_path_buf(),
            error,
        })?;
        let options = McapWriteOptions::new()
            .compression(Some(McapCompression::Lz4))
            .chunk_size(Some(CHUNK_BYTES))
            .profile("");
        let handle = ctx
            .mcap_writer_with_options(options)
            .create(BufWriter::new(file))
            .map_err(|error| RecordError::Mcap {
                path: path.to_path_buf(),
                error,
            })?;
        Ok(Recording {
            handle,
            path: path.to_path_buf(),
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Free bytes on the file's file system (`None` if unknown).
    pub fn free_bytes(&self) -> Option<u64> {
        free_bytes(&self.path)
    }

    /// True when the disk has less than [`RESERVE_BYTES`] free: time to close.
    pub fn disk_low(&self) -> bool {
        self.free_bytes().is_some_and(|f| f < RESERVE_BYTES)
    }

    /// Writes the last chunk, the summary and the footer; returns the file's size.
    pub fn close(self) -> Result<u64, RecordError> {
        let err = |error| RecordError::Mcap {
            path: self.path.clone(),
            error,
        };
        let writer = self.handle.close().map_err(err)?;
        let file = writer
            .into_inner()
            .map_err(|e| err(foxglove::FoxgloveError::from(e.into_error())))?;
        file.sync_all()
            .map_err(|e| err(foxglove::FoxgloveError::from(e)))?;
        Ok(file.metadata().map(|m| m.len()).unwrap_or(0))
    }
}

/// Free bytes (for an unprivileged writer) on the file system holding `path`.
pub fn free_bytes(path: &Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let c = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    // SAFETY: statvfs is plain integers, for which all-zero bytes are a valid value.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: `c` is a NUL-terminated string that outlives the call and `st` a
    // writable statvfs; statvfs(3) reads the one and writes only the other.
    if unsafe { libc::statvfs(c.as_ptr(), &mut st) } != 0 {
        return None;
    }
    Some(st.f_bavail as u64 * st.f_frsize as u64)
}
