//! What several commands share: finding the config, the shape of a group of
//! subcommands, input files that must exist, output files that appear whole or
//! not at all, and errors that end the command with a given exit code.

use std::path::{Path, PathBuf};

use anyhow::Context;
use isochron_config::{Config, LoadedConfig};
use isochron_exit::Fatal;

/// The config file: `--config`, else `$ISOCHRON_CONFIG`, else
/// `/etc/isochron/isochron.toml`.
pub fn config_path(arg: Option<PathBuf>) -> PathBuf {
    arg.or_else(|| std::env::var_os("ISOCHRON_CONFIG").map(PathBuf::from))
        .unwrap_or_else(|| PathBuf::from("/etc/isochron/isochron.toml"))
}

/// Loads the config named by `arg` (see [`config_path`]).
pub fn load_config(arg: Option<PathBuf>) -> anyhow::Result<LoadedConfig> {
    let path = config_path(arg);
    Config::load(&path).with_context(|| "invalid configuration")
}

/// The arguments of a command that is a group of subcommands (`isochron store
/// export`, `isochron plan now`, ...): `C` lists them.
#[derive(clap::Args)]
pub struct Subcommands<C: clap::Subcommand> {
    #[command(subcommand)]
    pub command: C,
}

/// The input file `path` that `what` (a flag, `--counts`, or an argument, `the
/// video`) names: it must exist and be a regular file, else the command ends
/// with 66 (`NO_INPUT`) and a message saying which and what was expected.
pub fn input_file(what: &str, path: &Path, expected: &str) -> Result<(), Fatal> {
    let found = match std::fs::metadata(path) {
        Ok(m) if m.is_file() => return Ok(()),
        Ok(m) if m.is_dir() => "a directory".to_string(),
        Ok(_) => "not a regular file".to_string(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => "no such file".to_string(),
        Err(e) => format!("cannot be read ({e})"),
    };
    Err(Fatal::new(
        isochron_exit::NO_INPUT,
        format!("{what} {}: {found}; expected {expected}", path.display()),
    ))
}

/// `error`, which ends the command with `code` (its message and causes are
/// `error`'s): for a failure the libraries do not classify, such as a file of
/// bad data read by the command itself (65).
pub fn with_code(code: i32, error: anyhow::Error) -> anyhow::Error {
    anyhow::Error::new(Coded {
        code,
        error: error.into(),
    })
}

/// An error of the command with the exit code it ends with ([`with_code`]).
#[derive(Debug)]
pub struct Coded {
    /// The exit code.
    pub code: i32,
    error: Box<dyn std::error::Error + Send + Sync + 'static>,
}

impl std::fmt::Display for Coded {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.error.fmt(f)
    }
}

/// Displayed as the error it wraps, so its causes are that error's causes.
impl std::error::Error for Coded {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        self.error.source()
    }
}

/// An output file that appears whole or not at all: it is written to a
/// temporary file beside it (same directory, same extension, so writers that
/// choose the format by the extension choose the same), which
/// [`OutFile::commit`] renames into place. Dropped without a commit (the
/// command failed), the temporary file is removed and `out` is untouched.
pub struct OutFile {
    out: PathBuf,
    temp: tempfile::TempPath,
}

/// Refuses (64) an output path `flag` names that is there but is not a regular
/// file: a device (`/dev/full`, `/dev/stdout`), a FIFO, a socket, a directory or
/// a symbolic link would be replaced by the file written, not written to.
pub fn output_target(flag: &str, out: &Path) -> anyhow::Result<()> {
    let found = match std::fs::symlink_metadata(out) {
        Err(_) => return Ok(()),
        Ok(m) if m.is_file() => return Ok(()),
        Ok(m) if m.is_symlink() => match std::fs::read_link(out) {
            Ok(target) => format!("a symbolic link (to {})", target.display()),
            Err(_) => "a symbolic link".to_string(),
        },
        Ok(m) if m.is_dir() => "a directory".to_string(),
        Ok(m) => {
            use std::os::unix::fs::FileTypeExt;
            let t = m.file_type();
            match () {
                _ if t.is_char_device() => "a character device",
                _ if t.is_block_device() => "a block device",
                _ if t.is_fifo() => "a FIFO",
                _ if t.is_socket() => "a socket",
                _ => "not a regular file",
            }
            .to_string()
        }
    };
    Err(with_code(
        isochron_exit::USAGE,
        anyhow::anyhow!(
            "{flag} {}: {found}, which writing would replace; give a new file's path or a regular file's",
            out.display()
        ),
    ))
}

impl OutFile {
    /// Makes the temporary file for `out` (named by `flag`): fails at once,
    /// before any work, when `out` is there but not a regular file
    /// ([`output_target`], 64) or its directory cannot be written.
    pub fn create(flag: &str, out: &Path) -> anyhow::Result<OutFile> {
        output_target(flag, out)?;
        let dir = match out.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        let name = out
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let suffix = out
            .extension()
            .map(|e| format!(".{}", e.to_string_lossy()))
            .unwrap_or_default();
        let temp = tempfile::Builder::new()
            .prefix(&format!(".{name}."))
            .suffix(&suffix)
            .tempfile_in(dir)
            .with_context(|| format!("{flag} {}: cannot write", out.display()))?
            .into_temp_path();
        Ok(OutFile {
            out: out.to_path_buf(),
            temp,
        })
    }

    /// Where to write: the temporary file.
    pub fn path(&self) -> &Path {
        &self.temp
    }

    /// Renames the temporary file to the output file.
    pub fn commit(self) -> anyhow::Result<()> {
        let out = self.out;
        self.temp
            .persist(&out)
            .with_context(|| format!("writing {}", out.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_output_file_appears_only_when_committed() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("x.png");
        let file = OutFile::create("--out", &out).unwrap();
        assert_eq!(file.path().extension().unwrap(), "png");
        std::fs::write(file.path(), b"half").unwrap();
        drop(file);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        let file = OutFile::create("--out", &out).unwrap();
        std::fs::write(file.path(), b"whole").unwrap();
        file.commit().unwrap();
        assert_eq!(std::fs::read(&out).unwrap(), b"whole");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        let err = OutFile::create("--out", Path::new("/nonexistent/dir/x.png")).err();
        assert!(
            format!("{:#}", err.unwrap()).contains("--out /nonexistent/dir/x.png: cannot write")
        );
    }

    #[test]
    fn an_output_path_that_is_not_a_regular_file_is_refused_and_left_alone() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("target.csv");
        std::fs::write(&target, b"kept").unwrap();
        let link = dir.path().join("link.csv");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let fifo = dir.path().join("fifo.csv");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let cases: [(&Path, &str); 4] = [
            (Path::new("/dev/full"), "a character device"),
            (&link, "a symbolic link (to "),
            (&fifo, "a FIFO"),
            (dir.path(), "a directory"),
        ];
        for (out, said) in cases {
            let err = OutFile::create("--out", out).err().unwrap();
            let text = format!("{err:#}");
            assert!(text.contains(said), "{text}");
            assert_eq!(crate::exit_code_of(&err), isochron_exit::USAGE, "{text}");
        }
        assert!(std::fs::symlink_metadata(&link).unwrap().is_symlink());
        assert_eq!(std::fs::read(&target).unwrap(), b"kept");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 3);
        assert!(output_target("--out", &target).is_ok());
    }

    #[test]
    fn a_missing_input_or_a_directory_is_66() {
        let dir = tempfile::tempdir().unwrap();
        let e = input_file("--counts", &dir.path().join("no.csv"), "a CSV file").unwrap_err();
        assert_eq!(e.code, isochron_exit::NO_INPUT);
        assert!(e.to_string().contains("no.csv: no such file"), "{e}");
        let e = input_file("the video", dir.path(), "a video file").unwrap_err();
        assert!(e.to_string().contains("a directory"), "{e}");
    }

    #[test]
    fn a_coded_error_keeps_its_message_and_causes() {
        let e = anyhow::anyhow!("cause").context("what failed");
        let coded = with_code(isochron_exit::DATA, e);
        assert_eq!(format!("{coded:#}"), "what failed: cause");
        assert_eq!(
            coded.downcast_ref::<Coded>().map(|c| c.code),
            Some(isochron_exit::DATA)
        );
    }
}
