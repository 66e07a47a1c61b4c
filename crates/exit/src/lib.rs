//! Exit codes (sysexits.h) and the one rule that maps a library error to one.
//! The services and the `isochron` command share this table (docs/operating.md,
//! "Exit codes"); clap's own usage errors exit with 2.
//!
//! Every library error type implements [`Classify`]; a binary turns any of them
//! into a [`Fatal`] with `?` (the blanket `From`), so no call site chooses an exit
//! code by hand. A supervisor must not restart a service that exits with a
//! permanent code ([`is_permanent`]): the same input would fail the same way.

/// A check failed or the command could not do its work (`doctor` found a
/// problem, an error no other code describes).
pub const FAILURE: i32 = 1;
/// `isochron status`: some service is not running (as LSB `status` says).
pub const NOT_RUNNING: i32 = 3;
/// Bad command line.
pub const USAGE: i32 = 64;
/// Input data is malformed (an undecodable video, a damaged store).
pub const DATA: i32 = 65;
/// Input does not exist (a missing video file).
pub const NO_INPUT: i32 = 66;
/// A needed service is unavailable (shared memory, iceoryx2, the disk).
pub const UNAVAILABLE: i32 = 69;
/// Internal error.
pub const SOFTWARE: i32 = 70;
/// Gave up waiting (`isochron tap --timeout`): trying again may succeed.
pub const TEMPFAIL: i32 = 75;
/// Configuration error.
pub const CONFIG: i32 = 78;

/// True for codes that restarting cannot fix.
pub fn is_permanent(code: i32) -> bool {
    matches!(code, USAGE | DATA | NO_INPUT | CONFIG)
}

/// An error that knows which exit code it ends a process with.
pub trait Classify: std::fmt::Display {
    /// The sysexits code of this error.
    fn exit_code(&self) -> i32;

    /// True if restarting cannot fix it (see [`is_permanent`]).
    fn is_permanent(&self) -> bool {
        is_permanent(self.exit_code())
    }
}

/// A failure that ends the process with `code` after logging `message`.
#[derive(Debug)]
pub struct Fatal {
    /// Exit code (one of this module's constants).
    pub code: i32,
    /// What went wrong and what to do.
    pub message: String,
}

impl Fatal {
    /// A failure with `code`.
    pub fn new(code: i32, message: impl Into<String>) -> Self {
        Fatal {
            code,
            message: message.into(),
        }
    }

    /// The same failure with `context` before its message (`context: message`).
    pub fn context(self, context: impl std::fmt::Display) -> Self {
        Fatal::new(self.code, format!("{context}: {}", self.message))
    }
}

impl std::fmt::Display for Fatal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

/// So a command can pass a stage's failure on with `?`; [`code_of_chain`] keeps
/// its code.
impl std::error::Error for Fatal {}

impl<E: Classify> From<E> for Fatal {
    fn from(e: E) -> Self {
        Fatal::new(e.exit_code(), e.to_string())
    }
}

/// A bad command line found after parsing (a value out of range): exit code
/// [`USAGE`]. The message says which argument and what was expected.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct UsageError(pub String);

impl Classify for UsageError {
    fn exit_code(&self) -> i32 {
        USAGE
    }
}

/// `Classify` for error types that always end with the same code, for the
/// libraries that define them: `always_exits_with!(CONFIG: ConfigError, ...);`.
#[macro_export]
macro_rules! always_exits_with {
    ($($code:ident: $($error:ty),+;)+) => {$($(
        impl $crate::Classify for $error {
            fn exit_code(&self) -> i32 {
                $crate::$code
            }
        }
    )+)+};
}

/// The exit code of a command that failed with `error` and the errors it was
/// caused by (context layers of `anyhow` and the like): the code of the first
/// one that is a [`Fatal`], a [`UsageError`] or that `classify` knows (the
/// libraries' error types), else [`FAILURE`].
pub fn code_of_chain<'a>(
    chain: impl IntoIterator<Item = &'a (dyn std::error::Error + 'static)>,
    classify: impl Fn(&(dyn std::error::Error + 'static)) -> Option<i32>,
) -> i32 {
    chain
        .into_iter()
        .find_map(|e| {
            if let Some(f) = e.downcast_ref::<Fatal>() {
                Some(f.code)
            } else if let Some(u) = e.downcast_ref::<UsageError>() {
                Some(u.exit_code())
            } else {
                classify(e)
            }
        })
        .unwrap_or(FAILURE)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn permanent_exit_codes() {
        assert!(is_permanent(CONFIG));
        assert!(is_permanent(NO_INPUT));
        assert!(!is_permanent(1));
        assert!(!is_permanent(UNAVAILABLE));
    }

    #[derive(Debug, thiserror::Error)]
    #[error("the disk is gone")]
    struct Gone;
    always_exits_with!(UNAVAILABLE: Gone;);

    #[test]
    fn a_chain_takes_the_code_of_its_first_known_error() {
        let io = std::io::Error::other("x");
        let none = |_: &(dyn std::error::Error + 'static)| None;
        let chain: Vec<&(dyn std::error::Error + 'static)> = vec![&io];
        assert_eq!(code_of_chain(chain, none), FAILURE);
        let usage = UsageError("--at: expected HH:MM".into());
        let chain: Vec<&(dyn std::error::Error + 'static)> = vec![&io, &usage];
        assert_eq!(code_of_chain(chain, none), USAGE);
        let chain: Vec<&(dyn std::error::Error + 'static)> = vec![&io, &Gone];
        let known = |e: &(dyn std::error::Error + 'static)| {
            e.downcast_ref::<Gone>().map(Classify::exit_code)
        };
        assert_eq!(code_of_chain(chain, known), UNAVAILABLE);
    }

    #[test]
    fn library_errors_become_fatal_with_their_code() {
        let f: Fatal = Gone.into();
        assert_eq!(f.code, UNAVAILABLE);
        assert_eq!(f.message, "the disk is gone");
        assert_eq!(
            f.context("camera 'a'").message,
            "camera 'a': the disk is gone"
        );
    }
}
