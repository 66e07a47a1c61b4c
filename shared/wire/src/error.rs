//! Why a received sample was rejected.

use crate::{LAYOUT_VERSION, MAGIC, Stream};

/// Why a received sample was rejected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WireError {
    /// Not an isochron sample at all.
    #[error(
        "bad magic {found:#010x} (expected {MAGIC:#010x}, \"ISOC\"): the publisher is not an isochron service"
    )]
    Magic {
        /// The magic found.
        found: u32,
    },
    /// Produced by another version of isochron.
    #[error(
        "layout version {found} (this build reads {LAYOUT_VERSION}): the publisher is another isochron version; run the same version on both ends"
    )]
    Version {
        /// The version found.
        found: u16,
    },
    /// A sample of another stream on this service.
    #[error("sample of stream '{found}' on a '{expected}' service")]
    Stream {
        /// The stream the consumer reads.
        expected: Stream,
        /// What the header says.
        found: String,
    },
    /// A sample of another camera on this camera's service.
    #[error("sample of camera '{found}' on camera '{expected}''s service")]
    Camera {
        /// Camera the consumer reads.
        expected: String,
        /// Camera in the header.
        found: String,
    },
    /// Sizes in the header do not match the sample or each other.
    #[error("{what} size mismatch: expected {expected}, found {found}")]
    Size {
        /// Which size.
        what: &'static str,
        /// What was expected.
        expected: String,
        /// What was found.
        found: String,
    },
    /// A field holds a value outside its range.
    #[error("invalid {field}: {reason}")]
    Field {
        /// The field.
        field: &'static str,
        /// Why it is invalid.
        reason: String,
    },
}
