//! The error of every iceoryx2 operation isochron makes, and its exit code.

/// An iceoryx2 failure, with what isochron was doing.
#[derive(Debug, thiserror::Error)]
#[error("iceoryx2: {context}: {detail}")]
pub struct IpcError {
    /// What was being done.
    pub context: String,
    /// iceoryx2's error.
    pub detail: String,
    /// Restarting cannot help (an unsafe node counter).
    pub permanent: bool,
}

/// What turns an iceoryx2 error into an [`IpcError`] while doing `context`.
pub(super) fn err(context: impl Into<String>) -> impl FnOnce(&dyn std::fmt::Display) -> IpcError {
    let context = context.into();
    move |e| IpcError {
        context,
        detail: format!("{e}"),
        permanent: false,
    }
}

impl isochron_exit::Classify for IpcError {
    /// Shared memory that is not there yet may come; an unsafe one stays unsafe.
    fn exit_code(&self) -> i32 {
        if self.permanent {
            isochron_exit::CONFIG
        } else {
            isochron_exit::UNAVAILABLE
        }
    }
}
