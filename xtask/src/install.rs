//! `cargo xtask install` (and the layout `cargo xtask deb` packages): binaries,
//! systemd units, sysusers/tmpfiles entries, examples, man pages, completions.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, bail};

use crate::{cargo, run};

/// One service of the stage table, as the docs example writes it
/// (`services.tsv`: binary, unit, `per-camera` or `site`, and `always` or the
/// config section that turns it on).
pub(crate) struct Service {
    pub(crate) binary: String,
    unit: String,
    per_camera: bool,
    when: String,
}

/// The services of the stage table, from what [`docs`] wrote into `docs_dir`.
pub(crate) fn services(docs_dir: &Path) -> anyhow::Result<Vec<Service>> {
    let path = docs_dir.join("services.tsv");
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("reading {} (made by cargo xtask docs)", path.display()))?;
    text.lines()
        .map(|line| match line.split('\t').collect::<Vec<_>>()[..] {
            [binary, unit, scope, when] => Ok(Service {
                binary: binary.into(),
                unit: unit.into(),
                per_camera: scope == "per-camera",
                when: when.into(),
            }),
            _ => bail!("{}: a malformed line: {line:?}", path.display()),
        })
        .collect()
}

/// The binaries a site runs: `isochron` and every service's.
pub(crate) fn binaries(docs_dir: &Path) -> anyhow::Result<Vec<String>> {
    let services = services(docs_dir)?;
    Ok(std::iter::once("isochron".to_string())
        .chain(services.into_iter().map(|s| s.binary))
        .collect())
}

/// Builds the binaries a site runs, in one build: the link and the costmap
/// bridge both carry DDS Security (isochron-dds's `security` feature; a site turns
/// it on with `link.security_dir` and `costmap.security_dir`, never by rebuilding).
pub(crate) fn build_shipped(release: bool) -> anyhow::Result<()> {
    let profile: &[&str] = if release { &["--release"] } else { &[] };
    run(cargo()
        .args(["build", "--workspace", "--bins"])
        .args(profile))
}

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
    lay_out_detector(l)?;
    lay_out_man_pages(l)?;
    lay_out_completions(l)
}

/// The [`binaries`] into `bin`, stripped of their debug sections if packaged.
fn lay_out_binaries(l: &Layout, bin: &Path) -> anyhow::Result<()> {
    let mut laid_out = Vec::new();
    for name in binaries(l.docs)? {
        let from = l.bins.join(&name);
        let to = l.under(&bin.join(&name));
        std::fs::copy(&from, &to).with_context(|| {
            format!(
                "installing {} (is it built? cargo build --workspace --bins)",
                from.display()
            )
        })?;
        laid_out.push(to);
    }
    if l.packaged {
        run(Command::new("strip").arg("--strip-debug").args(&laid_out))?;
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

/// The files of the people detectors `cargo xtask setup` installs that a site
/// runs with (not the conversion's sources): MoveNet and ONNX Runtime's library,
/// the SSD, and their licences.
const DETECTOR_FILES: [&str; 6] = [
    "movenet-multipose.onnx",
    "libonnxruntime.so",
    "LICENSE.movenet-multipose",
    "LICENSE.onnxruntime",
    "ssdlite-person.pb",
    "LICENSE.ssdlite-person",
];

/// The people detectors `cargo xtask setup` installed (`target/detector/`:
/// [`DETECTOR_FILES`]) into `share/isochron/detector/`, where the gate finds
/// them (`gate.detector.installed`); without any, a line says the site will run
/// HOG.
fn lay_out_detector(l: &Layout) -> anyhow::Result<()> {
    let from = l.root.join("target/detector");
    let files: Vec<PathBuf> = DETECTOR_FILES
        .iter()
        .map(|f| from.join(f))
        .filter(|p| p.is_file())
        .collect();
    if files.is_empty() {
        eprintln!(
            "xtask: no people detector in {} (cargo xtask setup installs it): the site will run HOG",
            from.display()
        );
        return Ok(());
    }
    let to = l.under(&l.prefix.join("share/isochron/detector"));
    std::fs::create_dir_all(&to)?;
    for file in files {
        let name = file.file_name().context("file name")?;
        std::fs::copy(&file, to.join(name))
            .with_context(|| format!("installing {}", file.display()))?;
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
    build_shipped(true)?;
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
    print_enable_steps(&prefix.join("bin"), &docs_dir)?;
    Ok(())
}

/// What to enable after installing (nothing is enabled by the install itself),
/// from the stage table's services in `docs_dir`.
pub(crate) fn print_enable_steps(bin: &Path, docs_dir: &Path) -> anyhow::Result<()> {
    let services = services(docs_dir)?;
    let unit = |s: &Service| s.unit.trim_end_matches(".service").to_string();
    let site: Vec<String> = (services.iter())
        .filter(|s| !s.per_camera && s.when == "always")
        .map(|s| format!("{}.service", unit(s)))
        .collect();
    println!(
        "  systemctl enable --now isochron.target {}",
        site.join(" ")
    );
    let per_camera: Vec<String> = (services.iter())
        .filter(|s| s.per_camera)
        .map(|s| {
            unit(s)
                .trim_start_matches("isochron-")
                .trim_end_matches('@')
                .to_string()
        })
        .collect();
    println!(
        "  for c in cam01; do systemctl enable --now isochron-{{{}}}@$c; done",
        per_camera.join(",")
    );
    for s in services.iter().filter(|s| s.when != "always") {
        println!(
            "  systemctl enable --now {:<24} # when the config has {}",
            unit(s),
            s.when
        );
    }
    println!(
        "  sudo -u isochron {}/isochron doctor               # checks it all",
        bin.display()
    );
    Ok(())
}
