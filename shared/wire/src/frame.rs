//! The `frames` stream: a header and the pixels of one frame.

use iceoryx2::prelude::ZeroCopySend;

use crate::blocks::check_side;
use crate::{CameraId, Preamble, Stream, WireError, u32_enum};

u32_enum! {
    /// Pixel layout of a frame.
    pub enum PixelFormat {
        /// One byte per pixel, luminance.
        Gray8 = 1,
        /// Three bytes per pixel, blue-green-red (OpenCV's order).
        Bgr8 = 2,
    }
}

impl PixelFormat {
    /// Bytes per pixel.
    pub fn channels(self) -> usize {
        match self {
            PixelFormat::Gray8 => 1,
            PixelFormat::Bgr8 => 3,
        }
    }
}

/// Header of a `frames` sample; the payload is `height * stride` bytes of pixels.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
#[type_name("isochron::FrameHeader")]
#[repr(C)]
pub struct FrameHeader {
    /// Common fields.
    pub preamble: Preamble,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Bytes per row (`width * channels`; rows are packed).
    pub stride: u32,
    /// A [`PixelFormat`] as `u32`.
    pub pixel_format: u32,
    /// Index of the frame in its source (0-based; for files, the frame number in the
    /// file, restarting when a file loops).
    pub source_index: u64,
}

impl FrameHeader {
    /// Validates the header against the sample's real payload length (bytes).
    pub fn validate(&self, camera: &CameraId, payload_bytes: usize) -> Result<(), WireError> {
        self.preamble
            .validate_then::<u8>(Stream::Frames, camera, payload_bytes, || {
                let format = PixelFormat::from_field(self.pixel_format, "pixel_format")?;
                check_side("width", self.width)?;
                check_side("height", self.height)?;
                let expected = self.width as usize * format.channels();
                if self.stride as usize != expected {
                    return Err(WireError::Size {
                        what: "row stride",
                        expected: expected.to_string(),
                        found: self.stride.to_string(),
                    });
                }
                let bytes = self.stride as usize * self.height as usize;
                if bytes != payload_bytes {
                    return Err(WireError::Size {
                        what: "frame",
                        expected: format!(
                            "{}x{}x{} = {bytes} bytes",
                            self.width,
                            self.height,
                            format.channels()
                        ),
                        found: format!("{payload_bytes} bytes"),
                    });
                }
                Ok(())
            })
    }

    /// The pixel format (valid after [`FrameHeader::validate`]).
    pub fn format(&self) -> PixelFormat {
        PixelFormat::from_u32(self.pixel_format).unwrap_or(PixelFormat::Gray8)
    }
}
