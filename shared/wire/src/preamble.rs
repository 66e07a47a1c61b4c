//! The fields every header starts with, and the camera id they carry.

use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::{CAMERA_ID_LEN, FLAG_END_OF_STREAM, LAYOUT_VERSION, MAGIC, Stream, WireError};

/// Checks a sample's magic number and layout version, the first fields of every
/// shared-memory type.
pub fn check_layout(magic: u32, layout_version: u16) -> Result<(), WireError> {
    if magic != MAGIC {
        return Err(WireError::Magic { found: magic });
    }
    if layout_version != LAYOUT_VERSION {
        return Err(WireError::Version {
            found: layout_version,
        });
    }
    Ok(())
}

/// A camera id as it travels in headers: ASCII, zero-padded.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend, Serialize, Deserialize)]
#[type_name("isochron::CameraId")]
#[repr(C)]
pub struct CameraId(pub [u8; CAMERA_ID_LEN]);

impl CameraId {
    /// Builds a camera id; `None` if `id` is empty, too long, or not `[A-Za-z0-9_-]`.
    pub fn new(id: &str) -> Option<CameraId> {
        if !is_valid_camera_id(id) {
            return None;
        }
        let mut bytes = [0u8; CAMERA_ID_LEN];
        bytes[..id.len()].copy_from_slice(id.as_bytes());
        Some(CameraId(bytes))
    }

    /// The id as text (lossy for bytes a foreign producer may have put there).
    pub fn as_str(&self) -> std::borrow::Cow<'_, str> {
        let end = self.0.iter().position(|&b| b == 0).unwrap_or(CAMERA_ID_LEN);
        String::from_utf8_lossy(&self.0[..end])
    }
}

/// True if `id` can name a camera: 1..=24 characters of `[A-Za-z0-9_-]`.
pub fn is_valid_camera_id(id: &str) -> bool {
    !id.is_empty()
        && id.len() <= CAMERA_ID_LEN
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
}

/// The fields every header starts with.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize)]
#[type_name("isochron::Preamble")]
#[repr(C)]
pub struct Preamble {
    /// Always [`MAGIC`].
    pub magic: u32,
    /// Always [`LAYOUT_VERSION`] of the producer.
    pub layout_version: u16,
    /// The [`Stream`] this sample belongs to, as `u16`.
    pub stream: u16,
    /// Camera that produced the data.
    pub camera: CameraId,
    /// Per-publisher sample counter, starting at 0, +1 per sample.
    pub sequence: u64,
    /// Capture time of the (last) frame this sample is about, UTC nanoseconds.
    pub capture_time_ns: i64,
    /// Wall-clock time (UTC ns) at which capture published the originating frame;
    /// carried through every stage to measure end-to-end latency.
    pub origin_wall_ns: i64,
    /// Number of payload elements that follow.
    pub payload_len: u32,
    /// Size of one payload element in bytes.
    pub element_size: u32,
    /// `FLAG_*` bits.
    pub flags: u32,
    /// Zero.
    pub reserved: u32,
}

impl Preamble {
    /// A preamble for `stream` of `camera` with the payload description filled in.
    pub fn new<T>(stream: Stream, camera: CameraId, sequence: u64, payload_len: usize) -> Self {
        Preamble {
            magic: MAGIC,
            layout_version: LAYOUT_VERSION,
            stream: stream as u16,
            camera,
            sequence,
            capture_time_ns: 0,
            origin_wall_ns: 0,
            payload_len: payload_len as u32,
            element_size: std::mem::size_of::<T>() as u32,
            flags: 0,
            reserved: 0,
        }
    }

    /// True if the end-of-stream flag is set.
    pub fn is_end_of_stream(&self) -> bool {
        self.flags & FLAG_END_OF_STREAM != 0
    }

    /// Checks magic, version, stream, camera and that the payload the sample really
    /// carries (`actual_len` elements of `T`) is what the header announces.
    pub fn validate<T>(
        &self,
        stream: Stream,
        camera: &CameraId,
        actual_len: usize,
    ) -> Result<(), WireError> {
        check_layout(self.magic, self.layout_version)?;
        if self.stream != stream as u16 {
            return Err(WireError::Stream {
                expected: stream,
                found: Stream::from_u16(self.stream)
                    .map(|s| s.name().to_string())
                    .unwrap_or_else(|| format!("unknown kind {}", self.stream)),
            });
        }
        if self.camera != *camera {
            return Err(WireError::Camera {
                expected: camera.as_str().into_owned(),
                found: self.camera.as_str().into_owned(),
            });
        }
        let element_size = std::mem::size_of::<T>() as u32;
        if self.element_size != element_size || self.payload_len as usize != actual_len {
            return Err(WireError::Size {
                what: "payload",
                expected: format!("{actual_len} elements of {element_size} bytes"),
                found: format!(
                    "{} elements of {} bytes",
                    self.payload_len, self.element_size
                ),
            });
        }
        Ok(())
    }

    /// [`Preamble::validate`], then, unless the sample is an end-of-stream marker
    /// (whose other header fields mean nothing), the stream's own checks `data`.
    pub fn validate_then<T>(
        &self,
        stream: Stream,
        camera: &CameraId,
        actual_len: usize,
        data: impl FnOnce() -> Result<(), WireError>,
    ) -> Result<(), WireError> {
        self.validate::<T>(stream, camera, actual_len)?;
        if self.is_end_of_stream() {
            return Ok(());
        }
        data()
    }
}
