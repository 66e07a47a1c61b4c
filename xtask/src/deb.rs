//! `cargo xtask deb`: the site's files under `/usr` as a Debian package.

use std::path::Path;
use std::process::Command;

use anyhow::{Context, bail};

use crate::install::{Layout, docs, lay_out, print_enable_steps};
use crate::{output, run};

/// The package's name.
const PACKAGE: &str = "isochron";

/// `postinst`: the user and directories from our own sysusers/tmpfiles entries,
/// and a daemon-reload when systemd runs. It enables and starts nothing.
const POSTINST: &str = r#"#!/bin/sh
# isochron postinst: the isochron user and its directories; enables nothing.
set -e
if [ "$1" = configure ]; then
    systemd-sysusers /usr/lib/sysusers.d/isochron.conf
    systemd-tmpfiles --create /usr/lib/tmpfiles.d/isochron.conf || true
    if [ -d /run/systemd/system ]; then
        systemctl --system daemon-reload >/dev/null || true
    fi
    echo "isochron: nothing is enabled; see /usr/share/doc/isochron/docs/operating.md (Installing on a base station)"
fi
exit 0
"#;

/// `prerm`: stops the running isochron units before their files go.
const PRERM: &str = r#"#!/bin/sh
# isochron prerm: stop the services before their binaries go.
set -e
if [ "$1" = remove ] && [ -d /run/systemd/system ]; then
    systemctl stop isochron.target 'isochron-*.service' >/dev/null 2>&1 || true
fi
exit 0
"#;

/// `postrm`: a daemon-reload after removal; on purge, the enablement links the
/// administrator made. The user and `/var/lib/isochron` (the learned activity)
/// are kept, as Debian keeps system users and data it cannot recreate.
const POSTRM: &str = r#"#!/bin/sh
# isochron postrm: forget the units; on purge, their enablement links too.
set -e
if [ "$1" = purge ]; then
    find /etc/systemd/system -path '*.wants/isochron*' -type l -delete 2>/dev/null || true
    echo "isochron: kept the isochron user and /var/lib/isochron (the learned activity)"
fi
if [ "$1" = remove ] || [ "$1" = purge ]; then
    if [ -d /run/systemd/system ]; then
        systemctl --system daemon-reload >/dev/null || true
    fi
fi
exit 0
"#;

/// `cargo xtask deb [--profile dev|release] [--no-build] [--out DIR]`: builds the
/// binaries (unless `--no-build`), lays the site out under `/usr` in a staging
/// tree ([`lay_out`]) and makes `DIR/isochron_<version>_<arch>.deb` with
/// `dpkg-deb --build` (default `DIR` = `target/deb`). Prints the package's path
/// as its last line.
pub(crate) fn deb(root: &Path, args: &[String]) -> anyhow::Result<()> {
    let mut profile = "release".to_string();
    let mut build = true;
    let mut out = root.join("target/deb");
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--profile" => profile = it.next().context("--profile needs dev or release")?.clone(),
            "--no-build" => build = false,
            "--out" => out = it.next().context("--out needs a directory")?.into(),
            other => bail!("deb: unknown argument '{other}'"),
        }
    }
    let (dir, release) = match profile.as_str() {
        "release" => ("release", true),
        "dev" => ("debug", false),
        other => bail!("deb: --profile is dev or release, not '{other}'"),
    };
    if build {
        crate::install::build_shipped(release)?;
    }
    let target = root.join("target").join(dir);
    let docs_dir = target.join("docs");
    man_pages(&target, &docs_dir, build, release)?;
    // dpkg-shlibdeps wants `debian/control` and the package under `debian/<name>`.
    let work = target.join("deb-work");
    let _ = std::fs::remove_dir_all(&work);
    let pkg = work.join("debian").join(PACKAGE);
    lay_out(&Layout {
        root,
        bins: &target,
        docs: &docs_dir,
        prefix: Path::new("/usr"),
        destdir: &pkg,
        packaged: true,
    })?;
    let (version, arch) = write_control(root, &work, &pkg)?;
    std::fs::create_dir_all(&out)?;
    let file = out.join(format!("{PACKAGE}_{version}_{arch}.deb"));
    // xz (dpkg's default) for releases; a dev package (the tests') is large and
    // only needs to be quick to make.
    let compression: &[&str] = if release {
        &["-Zxz"]
    } else {
        &["-Zgzip", "-z1"]
    };
    run(Command::new("dpkg-deb")
        .arg("--root-owner-group")
        .args(compression)
        .arg("--build")
        .arg(&pkg)
        .arg(&file))?;
    let size = std::fs::metadata(&file)?.len();
    eprintln!(
        "xtask: {} ({:.1} MiB); install: apt install {}",
        file.display(),
        size as f64 / (1 << 20) as f64,
        file.display()
    );
    println!("next, as root:");
    println!(
        "  $EDITOR /etc/isochron/isochron.toml   # from /usr/share/doc/isochron/examples/isochron.toml"
    );
    print_enable_steps(Path::new("/usr/bin"), &docs_dir)?;
    println!("{}", file.display());
    Ok(())
}

/// The man pages and completions into `docs_dir`: made by the docs example (run
/// by cargo after a build, else the one `cargo test` built in `target`).
fn man_pages(target: &Path, docs_dir: &Path, build: bool, release: bool) -> anyhow::Result<()> {
    // Without a build, the docs example is the one `cargo test` built: no cargo
    // run, which would wait for the lock a running `cargo test` holds.
    let example = target.join("examples/isochron-docs");
    if build {
        docs(docs_dir, release)?;
    } else if example.is_file() {
        run(Command::new(&example).arg(docs_dir))?;
    } else {
        bail!(
            "deb --no-build: {} is not built (cargo test --workspace builds it; or \
             cargo build -p isochron-cli --example isochron-docs{})",
            example.display(),
            if release { " --release" } else { "" }
        );
    }
    Ok(())
}

/// The package's metadata in `pkg/DEBIAN` (control file, maintainer scripts), its
/// copyright file, and its files' modes; returns its version and architecture.
fn write_control(root: &Path, work: &Path, pkg: &Path) -> anyhow::Result<(String, String)> {
    std::fs::create_dir_all(pkg.join("etc/isochron"))?;
    std::fs::write(
        pkg.join("usr/share/doc/isochron/copyright"),
        format!(
            "isochron {}\nLicense: {}\nSee the README for the project and its dependencies.\n",
            version(root)?,
            "MIT OR Apache-2.0"
        ),
    )?;
    let depends = depends(work)?;
    let control = pkg.join("DEBIAN");
    std::fs::create_dir_all(&control)?;
    let version = version(root)?;
    let arch = output(Command::new("dpkg").arg("--print-architecture"))?;
    let maintainer = match (std::env::var("DEBFULLNAME"), std::env::var("DEBEMAIL")) {
        (Ok(name), Ok(email)) => format!("{name} <{email}>"),
        _ => "isochron developers <isochron@localhost>".to_string(),
    };
    normalize_modes(pkg)?;
    let installed_kib = output(Command::new("du").args(["-sk", "--apparent-size"]).arg(pkg))?
        .split_whitespace()
        .next()
        .unwrap_or("0")
        .to_string();
    std::fs::write(
        control.join("control"),
        format!(
            "Package: {PACKAGE}\n\
             Version: {version}\n\
             Architecture: {arch}\n\
             Maintainer: {maintainer}\n\
             Installed-Size: {installed_kib}\n\
             Depends: {depends}\n\
             Section: misc\n\
             Priority: optional\n\
             Description: people activity from fixed cameras, for robot planning\n \
             isochron learns where and when people are active from fixed cameras and\n \
             feeds robots a cost map (ROS 2). The package installs the isochron command,\n \
             the services and their systemd units, and creates the isochron user;\n \
             it enables nothing by itself.\n"
        ),
    )?;
    for (name, text) in [("postinst", POSTINST), ("prerm", PRERM), ("postrm", POSTRM)] {
        let path = control.join(name);
        std::fs::write(&path, text)?;
        set_mode(&path, 0o755)?;
    }
    Ok((version, arch))
}

/// The workspace version (`[workspace.package] version` of the root Cargo.toml).
fn version(root: &Path) -> anyhow::Result<String> {
    let text = std::fs::read_to_string(root.join("Cargo.toml"))?;
    let mut in_package = false;
    for line in text.lines() {
        let line = line.trim();
        if line.starts_with('[') {
            in_package = line == "[workspace.package]";
        } else if in_package && let Some(v) = line.strip_prefix("version") {
            let v = v
                .trim_start()
                .trim_start_matches('=')
                .trim()
                .trim_matches('"');
            return Ok(v.to_string());
        }
    }
    bail!("Cargo.toml: no version in [workspace.package]")
}

/// The runtime libraries the binaries link, as Debian dependencies: from
/// `dpkg-shlibdeps` (package dpkg-dev) when it is installed, else OpenCV's
/// runtime packages by name, and what the postinst runs (systemd-sysusers).
fn depends(work: &Path) -> anyhow::Result<String> {
    let sysusers = "systemd | systemd-standalone-sysusers";
    let has_shlibdeps = Command::new("dpkg-shlibdeps")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !has_shlibdeps {
        eprintln!("xtask: dpkg-shlibdeps missing (package dpkg-dev): naming OpenCV's libraries");
        return Ok(format!(
            "libopencv-core406t64 | libopencv-core406, \
             libopencv-imgproc406t64 | libopencv-imgproc406, \
             libopencv-videoio406t64 | libopencv-videoio406, \
             libopencv-video406t64 | libopencv-video406, \
             libopencv-objdetect406t64 | libopencv-objdetect406, \
             libopencv-dnn406t64 | libopencv-dnn406, libssl3t64 | libssl3, libc6, libgcc-s1, \
             libstdc++6, {sysusers}"
        ));
    }
    std::fs::write(
        work.join("debian/control"),
        format!("Source: {PACKAGE}\n\nPackage: {PACKAGE}\nArchitecture: any\n"),
    )?;
    let mut cmd = Command::new("dpkg-shlibdeps");
    cmd.arg("-O").current_dir(work);
    // Every binary laid out in the package (the stage table's and `isochron`).
    for entry in std::fs::read_dir(work.join("debian").join(PACKAGE).join("usr/bin"))? {
        let name = entry?.file_name();
        cmd.arg(format!(
            "-edebian/{PACKAGE}/usr/bin/{}",
            name.to_string_lossy()
        ));
    }
    let line = output(&mut cmd)?;
    let shlibs = line
        .lines()
        .find_map(|l| l.strip_prefix("shlibs:Depends="))
        .with_context(|| format!("dpkg-shlibdeps printed no shlibs:Depends: {line}"))?;
    Ok(format!("{shlibs}, {sysusers}"))
}

fn set_mode(path: &Path, mode: u32) -> anyhow::Result<()> {
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode))
        .with_context(|| format!("chmod {mode:o} {}", path.display()))
}

/// Directories 0755, files 0644, the binaries 0755: whatever the umask and the
/// checkout's modes were.
fn normalize_modes(dir: &Path) -> anyhow::Result<()> {
    set_mode(dir, 0o755)?;
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        if path.is_dir() {
            normalize_modes(&path)?;
        } else {
            let executable = path.parent().is_some_and(|p| p.ends_with("usr/bin"));
            set_mode(&path, if executable { 0o755 } else { 0o644 })?;
        }
    }
    Ok(())
}
