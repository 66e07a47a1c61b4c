//! The streams of one camera, by number and by name.

/// The streams of one camera, as named in docs/ARCHITECTURE.md, "Processes and streams".
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[repr(u16)]
pub enum Stream {
    /// Frame header + pixels, camera rate.
    Frames = 1,
    /// Motion header + one [`BlockMotion`] per block, camera rate.
    Motion = 2,
    /// Activity header + one [`BlockActivity`] per block, 1 Hz.
    Activity = 3,
    /// Event start/end records.
    Events = 4,
    /// Detector results for gated frames.
    Detections = 5,
}

impl Stream {
    /// All streams, in pipeline order.
    pub const ALL: [Stream; 5] = [
        Stream::Frames,
        Stream::Motion,
        Stream::Activity,
        Stream::Events,
        Stream::Detections,
    ];

    /// The stream's name as used in service names and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Stream::Frames => "frames",
            Stream::Motion => "motion",
            Stream::Activity => "activity",
            Stream::Events => "events",
            Stream::Detections => "detections",
        }
    }

    /// Parses a stream name (`frames`, `motion`, ...).
    pub fn from_name(name: &str) -> Option<Stream> {
        Stream::ALL.into_iter().find(|s| s.name() == name)
    }

    /// The stream whose number a preamble carries.
    pub(crate) fn from_u16(v: u16) -> Option<Stream> {
        Stream::ALL.into_iter().find(|s| *s as u16 == v)
    }
}

impl std::fmt::Display for Stream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}
