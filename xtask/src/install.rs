//! `cargo xtask install` (and the layout `cargo xtask deb` packages): binaries,
//! systemd units, sysusers/tmpfiles entries, examples, man pages, completions.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, bail};

use crate::{cargo, run};

/// The binaries a site runs.
pub(crate) const BINARIES: [&str; 9] = [
    "isochron",
    "isochron-capture",
    "isochron-motion",
    "isochron-cascade",
    "isochron-gate",
    "isochron-costmap",
    "isochron-exporter",
    "isochron-link",
    "isochron-mqtt",
];

/// Writes the man pages (`isochron` and the services) and completions of
/// `isochron` into `out` (see the `isochron-docs` example of the cli crate).
pub(crate) fn docs(out: &Path, release: bool) -> anyhow::Result<()> {
    let mut cmd = cargo();
    cmd.args([
        "run",
        "-q",
        "-p",
        "isochron-cli",
        "--example",
        "isochron-docs",
    ]);
    if release {
        cmd.arg("--release");
    }
    run(cmd.arg("--").arg(out))
}

/// Where [`lay_out`] puts a site's files, and from where.
pub(crate) struct Layout<'a> {
    /// The repository.
    pub(crate) root: &'a Path,
    /// The built binaries (`target/<profile>`).
    pub(crate) bins: &'a Path,
    /// What [`docs`] wrote (`man/`, `completions/`).
    pub(crate) docs: &'a Path,
    /// The installation prefix: `/usr/local`, or `/usr` for the package.
    pub(crate) prefix: &'a Path,
    /// Everything goes under this directory (DESTDIR; the package's root).
    pub(crate) destdir: &'a Path,
    /// The package's way: man pages gzipped (Debian policy), binaries stripped of
    /// their debug sections (symbol names stay, for backtraces).
    pub(crate) packaged: bool,
}

impl Layout<'_> {
    /// Where `p` (an absolute path on the target system) goes: under `destdir`.
    fn under(&self, p: &Path) -> PathBuf {
        self.destdir.join(p.strip_prefix("/").unwrap_or(p))
    }
}

/// Installs the binaries, systemd units, sysusers/tmpfiles entries, README and
/// the guides in `docs/`, example config, Grafana dashboard, alert rules, man pages and completions
/// under `destdir/prefix` (`cargo xtask install` and `cargo xtask deb`).
pub(crate) fn lay_out(l: &Layout) -> anyhow::Result<()> {
    let prefix = l.prefix;
    let bin = prefix.join("bin");
    let units = prefix.join("lib/systemd/system");
    let doc = prefix.join("share/doc/isochron");
    for dir in [
        &bin,
        &units,
        &prefix.join("lib/sysusers.d"),
        &prefix.join("lib/tmpfiles.d"),
        &doc.join("examples"),
        &doc.join("docs"),
    ] {
        std::fs::create_dir_all(l.under(dir))?;
    }
    lay_out_binaries(l, &bin)?;
    lay_out_units(l, &bin, &units)?;
    lay_out_files(l, &doc)?;
    lay_out_man_pages(l)?;
    lay_out_completions(l)
}

/// The [`BINARIES`] into `bin`, stripped of their debug sections if packaged.
fn lay_out_binaries(l: &Layout, bin: &Path) -> anyhow::Result<()> {
    let mut binaries = Vec::new();
    for name in BINARIES {
        let from = l.bins.join(name);
        let to = l.under(&bin.join(name));
        std::fs::copy(&from, &to).with_context(|| {
            format!(
                "installing {} (is it built? cargo build --workspace --bins)",
                from.display()
            )
        })?;
        binaries.push(to);
    }
    if l.packaged {
        run(Command::new("strip").arg("--strip-debug").args(&binaries))?;
    }
    Ok(())
}

/// The systemd units and their drop-ins of `systemd/` into `units`, pointing at
/// the binaries in `bin`.
fn lay_out_units(l: &Layout, bin: &Path, units: &Path) -> anyhow::Result<()> {
    // Units name /usr/bin; point them at this prefix.
    let bin_text = format!("{}/", bin.display());
    let copy_unit = |from: &Path, to: &Path| -> anyhow::Result<()> {
        let text = std::fs::read_to_string(from)?.replace("/usr/bin/", &bin_text);
        std::fs::write(to, text).with_context(|| format!("writing {}", to.display()))
    };
    for entry in std::fs::read_dir(l.root.join("systemd"))? {
        let path = entry?.path();
        let name = path.file_name().context("unit name")?.to_owned();
        if path.is_dir() {
            let target = l.under(&units.join(&name));
            std::fs::create_dir_all(&target)?;
            for inner in std::fs::read_dir(&path)? {
                let inner = inner?.path();
                copy_unit(
                    &inner,
                    &target.join(inner.file_name().context("drop-in name")?),
                )?;
            }
        } else if path
            .extension()
            .is_some_and(|e| e == "service" || e == "target")
        {
            copy_unit(&path, &l.under(&units.join(&name)))?;
        }
    }
    Ok(())
}

/// The sysusers/tmpfiles entries, and the README, the guides (`docs/*.md`) and
/// examples into `doc`.
fn lay_out_files(l: &Layout, doc: &Path) -> anyhow::Result<()> {
    let prefix = l.prefix;
    let copies = [
        (
            "systemd/isochron.sysusers",
            prefix.join("lib/sysusers.d/isochron.conf"),
        ),
        (
            "systemd/isochron.tmpfiles",
            prefix.join("lib/tmpfiles.d/isochron.conf"),
        ),
        ("README.md", doc.join("README.md")),
        (
            "config/site.example.toml",
            doc.join("examples/isochron.toml"),
        ),
        (
            "deploy/grafana/isochron-dashboard.json",
            doc.join("examples/isochron-dashboard.json"),
        ),
        (
            "deploy/prometheus/isochron-alerts.yml",
            doc.join("examples/isochron-alerts.yml"),
        ),
    ];
    for (from, to) in copies {
        std::fs::copy(l.root.join(from), l.under(&to))
            .with_context(|| format!("installing {from}"))?;
    }
    for entry in std::fs::read_dir(l.root.join("docs"))? {
        let from = entry?.path();
        if let Some(name) = from
            .file_name()
            .filter(|_| from.extension() == Some("md".as_ref()))
        {
            std::fs::copy(&from, l.under(&doc.join("docs").join(name)))
                .with_context(|| format!("installing {}", from.display()))?;
        }
    }
    Ok(())
}

/// The man pages: `isochron*.1` (the command) and `isochron-*.8` (the services),
/// gzipped if packaged.
fn lay_out_man_pages(l: &Layout) -> anyhow::Result<()> {
    let mut pages = Vec::new();
    for entry in std::fs::read_dir(l.docs.join("man"))? {
        let path = entry?.path();
        let section = path.extension().context("a man page's section")?;
        let dir = l.under(
            &l.prefix
                .join("share/man")
                .join(format!("man{}", section.to_string_lossy())),
        );
        std::fs::create_dir_all(&dir)?;
        let to = dir.join(path.file_name().context("file name")?);
        std::fs::copy(&path, &to)?;
        pages.push(to);
    }
    if l.packaged {
        // -n: no name or time stamp in the header, so the package is reproducible.
        run(Command::new("gzip").arg("-9nf").args(&pages))?;
    }
    Ok(())
}

/// The bash, zsh and fish completions of `isochron`.
fn lay_out_completions(l: &Layout) -> anyhow::Result<()> {
    let completions = l.docs.join("completions");
    for (file, dir, name) in [
        (
            "isochron.bash",
            "share/bash-completion/completions",
            "isochron",
        ),
        ("_isochron", "share/zsh/vendor-completions", "_isochron"),
        (
            "isochron.fish",
            "share/fish/vendor_completions.d",
            "isochron.fish",
        ),
    ] {
        let to = l.under(&l.prefix.join(dir));
        std::fs::create_dir_all(&to)?;
        std::fs::copy(completions.join(file), to.join(name))?;
    }
    Ok(())
}

pub(crate) fn install(root: &Path, args: &[String]) -> anyhow::Result<()> {
    let mut prefix = PathBuf::from("/usr/local");
    let mut destdir = PathBuf::from("/");
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--prefix" => prefix = it.next().context("--prefix needs a path")?.into(),
            "--destdir" => destdir = it.next().context("--destdir needs a path")?.into(),
            other => bail!("install: unknown argument '{other}'"),
        }
    }
    anyhow::ensure!(prefix.is_absolute(), "--prefix must be an absolute path");
    run(cargo().args(["build", "--release", "--workspace", "--bins"]))?;
    let docs_dir = root.join("target/release/docs");
    let _ = std::fs::remove_dir_all(&docs_dir);
    docs(&docs_dir, true)?;
    lay_out(&Layout {
        root,
        bins: &root.join("target/release"),
        docs: &docs_dir,
        prefix: &prefix,
        destdir: &destdir,
        packaged: false,
    })?;
    let under = |p: &Path| destdir.join(p.strip_prefix("/").unwrap_or(p));
    let config = under(Path::new("/etc/isochron/isochron.toml"));
    if !config.exists() {
        std::fs::create_dir_all(config.parent().expect("config dir"))?;
        std::fs::copy(root.join("config/site.example.toml"), &config)?;
    }
    println!("installed under {}", under(&prefix).display());
    println!("next, as root:");
    println!(
        "  systemd-sysusers && systemd-tmpfiles --create    # the isochron user, its state dir, /tmp/iceoryx2"
    );
    println!("  $EDITOR /etc/isochron/isochron.toml              # cameras, zones, floor points");
    println!("  systemctl daemon-reload");
    print_enable_steps(&prefix.join("bin"));
    Ok(())
}

/// What to enable after installing (nothing is enabled by the install itself).
pub(crate) fn print_enable_steps(bin: &Path) {
    println!("  systemctl enable --now isochron.target isochron-costmap.service");
    println!(
        "  for c in cam01; do systemctl enable --now isochron-{{capture,motion,cascade,gate}}@$c; done"
    );
    println!(
        "  systemctl enable --now isochron-exporter         # optional: metrics at 127.0.0.1:9464"
    );
    println!(
        "  systemctl enable --now isochron-mqtt             # optional: events to [mqtt] broker"
    );
    println!(
        "  sudo -u isochron {}/isochron doctor               # checks it all",
        bin.display()
    );
}
