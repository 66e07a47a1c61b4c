//! Exit codes (sysexits.h) and the one rule that maps a library error to one.
//! The services and the `isochron` command share this table (docs/operating.md,
//! "Exit codes"); clap's own usage errors exit with 2 (the `isochron` command
//! ends a flag value its value parsers refuse with [`USAGE`]).
//!
//! Every library error type implements [`Classify`]; a binary turns any of them
//! into a [`Fatal`] with `?` (the blanket `From`), so no call site chooses an exit
//! code by hand. A supervisor must not restart a service that exits with a
//! permanent code ([`is_permanent`]): the same input would fail the same way.
//!
//! A [`Fatal`] keeps the error it was made from as its cause (`source()`), so the
//! chain reaches the end of the process intact: the exit code is read from it
//! ([`code_of_chain`]) and the last log line shows all of it (`{:#}`, or
//! [`chain`] for any error: `context: error: cause`).

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
/// Stopped by SIGINT (Ctrl-C) or SIGTERM before it finished (128 + SIGINT, as
/// shells report it); what the command had done is kept and said.
pub const INTERRUPTED: i32 = 130;

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

/// A failure that ends the process with `code`, keeping what caused it.
///
/// Its `Display` is its own message (`{}`), or the whole chain of causes with
/// the alternate flag (`{:#}`: `context: message: cause: ...`), which is how a
/// process logs the failure it ends with. [`std::error::Error::source`] gives
/// the causes, so [`code_of_chain`], `anyhow`'s `{:#}` and a debugger see the
/// library errors themselves, not strings made of them.
pub struct Fatal {
    /// Exit code (one of this module's constants).
    pub code: i32,
    /// Its own message; `None` when it is the `error` it was made from
    /// ([`From`]: then it displays as that error and its causes are that
    /// error's causes).
    message: Option<String>,
    /// What caused it.
    error: Option<Box<dyn std::error::Error + Send + Sync + 'static>>,
}

impl Fatal {
    /// A failure with `code`, caused by nothing else: `message` says what went
    /// wrong and what to do.
    pub fn new(code: i32, message: impl Into<String>) -> Self {
        Fatal {
            code,
            message: Some(message.into()),
            error: None,
        }
    }

    /// A failure with `code` that `message` describes, caused by `source` (shown
    /// after it in the chain: `message: source`).
    pub fn with_source(
        code: i32,
        message: impl Into<String>,
        source: impl Into<Box<dyn std::error::Error + Send + Sync + 'static>>,
    ) -> Self {
        Fatal {
            code,
            message: Some(message.into()),
            error: Some(source.into()),
        }
    }

    /// The same failure (same code) with `context` before it: displayed as
    /// `context`, the failure becomes its source (`{:#}`: `context: failure`).
    pub fn context(self, context: impl std::fmt::Display) -> Self {
        let code = self.code;
        Fatal::with_source(code, context.to_string(), self)
    }

    /// The whole chain as one line: `message: cause: cause ...` (what `{:#}`
    /// prints).
    pub fn chain(&self) -> String {
        format!("{self:#}")
    }
}

impl std::fmt::Debug for Fatal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Fatal({}, {self:#})", self.code)
    }
}

impl std::fmt::Display for Fatal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (&self.message, &self.error) {
            (Some(message), _) => f.write_str(message)?,
            (None, Some(error)) => write!(f, "{error}")?,
            (None, None) => {}
        }
        if f.alternate() {
            let mut cause = std::error::Error::source(self);
            while let Some(c) = cause {
                write!(f, ": {c}")?;
                cause = c.source();
            }
        }
        Ok(())
    }
}

/// So a command can pass a stage's failure on with `?`; [`code_of_chain`] keeps
/// its code, and the causes stay reachable through `source()`.
impl std::error::Error for Fatal {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        let error = self.error.as_deref()?;
        if self.message.is_some() {
            Some(error)
        } else {
            // It displays as `error`: its causes are `error`'s.
            error.source()
        }
    }
}

/// A library error ends the process with the code it classifies itself with,
/// and stays the failure's cause (not a string made of it).
impl<E: Classify + std::error::Error + Send + Sync + 'static> From<E> for Fatal {
    fn from(e: E) -> Self {
        Fatal {
            code: e.exit_code(),
            message: None,
            error: Some(Box::new(e)),
        }
    }
}

/// The chain of `error` and its causes as one line, `error: cause: cause ...`:
/// how a log line or a message shows an error (`anyhow`'s `{:#}` for any error).
pub fn chain(error: &(dyn std::error::Error + 'static)) -> String {
    let mut line = error.to_string();
    let mut cause = error.source();
    while let Some(c) = cause {
        line.push_str(": ");
        line.push_str(&c.to_string());
        cause = c.source();
    }
    line
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
        assert_eq!(f.to_string(), "the disk is gone");
        let f = f.context("camera 'a'");
        assert_eq!(f.code, UNAVAILABLE);
        assert_eq!(f.to_string(), "camera 'a'");
        assert_eq!(f.chain(), "camera 'a': the disk is gone");
    }

    /// An error with a cause, as a library's error wrapping an I/O error.
    #[derive(Debug, thiserror::Error)]
    #[error("writing the store")]
    struct Store(#[source] std::io::Error);
    always_exits_with!(UNAVAILABLE: Store;);

    #[test]
    fn a_fatal_keeps_the_chain_of_what_caused_it() {
        let io = std::io::Error::new(std::io::ErrorKind::StorageFull, "no space left");
        let f: Fatal = Store(io).into();
        let f = f.context("cam01");
        assert_eq!(format!("{f}"), "cam01");
        assert_eq!(format!("{f:#}"), "cam01: writing the store: no space left");
        // The causes are the errors themselves, not strings made of them.
        let mut causes = Vec::new();
        let mut cause = std::error::Error::source(&f);
        while let Some(c) = cause {
            causes.push(c);
            cause = c.source();
        }
        assert_eq!(
            causes.len(),
            2,
            "the Fatal made from Store, then the I/O error"
        );
        let io = causes[1]
            .downcast_ref::<std::io::Error>()
            .expect("an io::Error");
        assert_eq!(io.kind(), std::io::ErrorKind::StorageFull);
        // anyhow renders it the same way, and the exit code still comes through.
        let e = anyhow::Error::from(f).context("isochron replay");
        assert_eq!(
            format!("{e:#}"),
            "isochron replay: cam01: writing the store: no space left"
        );
        let none = |_: &(dyn std::error::Error + 'static)| None;
        let chain = e.chain().map(|c| c as &(dyn std::error::Error + 'static));
        assert_eq!(code_of_chain(chain, none), UNAVAILABLE);
        assert_eq!(
            chain_line(&Store(std::io::Error::other("gone"))),
            "writing the store: gone"
        );
    }

    fn chain_line(e: &(dyn std::error::Error + 'static)) -> String {
        chain(e)
    }

    #[test]
    fn a_fatal_with_a_source_shows_it_after_its_message() {
        let f = Fatal::with_source(
            CONFIG,
            "site.toml",
            std::io::Error::other("permission denied"),
        );
        assert_eq!(f.to_string(), "site.toml");
        assert_eq!(f.chain(), "site.toml: permission denied");
        assert_eq!(Fatal::new(DATA, "bad").chain(), "bad");
    }
}
