//! The Debian package (`cargo xtask deb`): made from the dev-profile binaries the
//! tests already use (no release build in CI), its metadata, files and maintainer
//! scripts checked with `dpkg-deb`; where `CI=true` (a throwaway root machine) it
//! is installed with `dpkg -i`, its user and files verified, nothing enabled, and
//! purged again.

use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use isochron_runtime::topology::StageKind;
use isochron_tests::{Proc, bin, repo_root};

/// Every binary of a site: the CLI and each stage's binary.
fn binaries() -> std::collections::BTreeSet<&'static str> {
    std::iter::once("isochron")
        .chain(StageKind::services().map(StageKind::binary))
        .collect()
}

/// The units that could be enabled: after the install, none may be.
const UNITS: [&str; 5] = [
    "isochron.target",
    "isochron-costmap.service",
    "isochron-exporter.service",
    "isochron-link.service",
    "isochron-capture@cam01.service",
];

/// Runs `program args`, which must succeed, and returns its stdout.
fn ok(program: &str, args: &[&str]) -> String {
    let out = Command::new(program)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("{program}: {e}"));
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{program} {args:?}: {}\n{stdout}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

/// Makes the package with `cargo xtask deb --profile dev --no-build` into `out`.
fn make_package(out: &Path) -> PathBuf {
    let mut xtask = Proc::spawn(
        &bin("xtask"),
        &[
            "deb",
            "--profile",
            "dev",
            "--no-build",
            "--out",
            out.to_str().unwrap(),
        ],
    );
    let done = xtask.finish(Duration::from_secs(120));
    assert!(done.status.success(), "xtask deb: {}", done.stderr);
    let path = PathBuf::from(done.stdout.lines().last().expect("a last line").trim());
    assert!(path.is_file(), "{}\n{}", done.stdout, done.stderr);
    path
}

/// Purges the package when dropped, so that a failed check leaves no install.
struct Installed;

impl Drop for Installed {
    fn drop(&mut self) {
        let _ = Command::new("dpkg").args(["--purge", "isochron"]).status();
    }
}

#[test]
fn the_package_holds_the_site_and_installs_enabling_nothing() {
    let t0 = Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let deb = make_package(dir.path());
    let deb_arg = deb.to_str().unwrap();
    let built = t0.elapsed();

    // Metadata: name, version from Cargo.toml, this machine's architecture, the
    // OpenCV runtime libraries, and the three maintainer scripts.
    let info = ok("dpkg-deb", &["--info", deb_arg]);
    let arch = ok("dpkg", &["--print-architecture"]);
    for field in [
        "Package: isochron".to_string(),
        format!("Version: {}", env!("CARGO_PKG_VERSION")),
        format!("Architecture: {}", arch.trim()),
    ] {
        assert!(info.contains(&field), "{field}\n{info}");
    }
    let depends = info
        .lines()
        .find_map(|l| l.trim().strip_prefix("Depends: "))
        .unwrap_or_else(|| panic!("no Depends\n{info}"));
    assert!(
        depends.contains("libopencv-core") && depends.contains("systemd"),
        "{depends}"
    );
    for script in ["postinst", "prerm", "postrm"] {
        assert!(info.contains(script), "{script}\n{info}");
    }
    let postinst = ok("dpkg-deb", &["--info", deb_arg, "postinst"]);
    assert!(
        postinst.contains("systemd-sysusers /usr/lib/sysusers.d/isochron.conf")
            && postinst.contains("systemd-tmpfiles --create /usr/lib/tmpfiles.d/isochron.conf"),
        "{postinst}"
    );
    for verb in ["enable", "start", "restart", "--now"] {
        assert!(
            !postinst.contains(&format!("systemctl {verb}")),
            "the postinst enables or starts something:\n{postinst}"
        );
    }

    // Files: every binary, the units and drop-ins, sysusers/tmpfiles, the example
    // config, man pages of the CLI and of the services, completions; owned by
    // root, nothing under /home.
    let contents = ok("dpkg-deb", &["--contents", deb_arg]);
    let paths: Vec<&str> = contents
        .lines()
        .filter_map(|l| l.split_whitespace().nth(5))
        .collect();
    let mut expected: Vec<String> = binaries()
        .iter()
        .map(|b| format!("./usr/bin/{b}"))
        .collect();
    // Every unit of the repository, and a service man page for every stage's binary.
    for unit in std::fs::read_dir(repo_root().join("systemd")).unwrap() {
        let name = unit.unwrap().file_name().into_string().unwrap();
        if name.ends_with(".service") || name.ends_with(".target") {
            expected.push(format!("./usr/lib/systemd/system/{name}"));
        }
    }
    for b in binaries().into_iter().filter(|b| *b != "isochron") {
        expected.push(format!("./usr/share/man/man8/{b}.8.gz"));
    }
    expected.extend(
        [
            "./usr/lib/systemd/system/isochron-.service.d/10-hardening.conf",
            "./usr/lib/sysusers.d/isochron.conf",
            "./usr/lib/tmpfiles.d/isochron.conf",
            "./usr/share/doc/isochron/examples/isochron.toml",
            "./usr/share/doc/isochron/copyright",
            "./usr/share/doc/isochron/docs/operating.md",
            "./usr/share/doc/isochron/docs/configuration.md",
            "./usr/share/man/man1/isochron.1.gz",
            "./usr/share/man/man1/isochron-up.1.gz",
            "./usr/share/man/man1/isochron-costmap.1.gz",
            "./usr/share/bash-completion/completions/isochron",
            "./usr/share/zsh/vendor-completions/_isochron",
            "./usr/share/fish/vendor_completions.d/isochron.fish",
            // The people detector setup installed, where the gate finds it.
            "./usr/share/isochron/detector/movenet-multipose.onnx",
            "./usr/share/isochron/detector/libonnxruntime.so",
            "./usr/share/isochron/detector/LICENSE.movenet-multipose",
            "./usr/share/isochron/detector/LICENSE.onnxruntime",
            "./usr/share/isochron/detector/ssdlite-person.pb",
            "./usr/share/isochron/detector/LICENSE.ssdlite-person",
        ]
        .map(String::from),
    );
    for path in &expected {
        assert!(
            paths.contains(&path.as_str()),
            "{path} missing:\n{contents}"
        );
    }
    for line in contents.lines() {
        assert!(line.contains(" root/root "), "not root's: {line}");
    }
    assert!(
        paths.iter().all(|p| p.starts_with("./usr/")
            || p.starts_with("./etc/isochron")
            || ["./", "./etc/"].contains(p)),
        "{contents}"
    );
    // No text file names the build directory or a home directory.
    let tree = dir.path().join("tree");
    ok("dpkg-deb", &["-x", deb_arg, tree.to_str().unwrap()]);
    let root = repo_root().display().to_string();
    let mut texts = 0;
    for path in &paths {
        let file = tree.join(path.trim_start_matches("./"));
        // Binaries: the programs, the detectors' networks and ONNX Runtime.
        if path.starts_with("./usr/bin/")
            || [".pb", ".onnx", ".so"].iter().any(|e| path.ends_with(e))
            || !file.is_file()
        {
            continue;
        }
        let bytes = std::fs::read(&file).unwrap();
        let text = if path.ends_with(".gz") {
            ok("zcat", &[file.to_str().unwrap()])
        } else {
            String::from_utf8(bytes).unwrap_or_else(|_| panic!("{path} is not text"))
        };
        assert!(
            !text.contains(&root) && !text.contains("/home/") && !text.contains("/root/"),
            "{path} names a build or home directory"
        );
        texts += 1;
    }
    let unit =
        std::fs::read_to_string(tree.join("usr/lib/systemd/system/isochron-costmap.service"))
            .unwrap();
    assert!(
        unit.contains("ExecStart=/usr/bin/isochron-costmap --config /etc/isochron/isochron.toml"),
        "{unit}"
    );
    println!(
        "package: {} bytes, {} entries ({texts} text files checked), made in {:.1} s",
        std::fs::metadata(&deb).unwrap().len(),
        paths.len(),
        built.as_secs_f64()
    );

    if std::env::var("CI").as_deref() != Ok("true") {
        println!("CI is not 'true': the package is not installed on this machine");
        return;
    }
    install_and_remove(&deb);
    println!("checked in {:.1} s", t0.elapsed().as_secs_f64());
}

/// `dpkg -i`, the user and files there, `isochron --version` from /usr/bin,
/// nothing enabled, then `dpkg --purge`.
fn install_and_remove(deb: &Path) {
    // The tmpfiles entry takes /tmp/iceoryx2 over for the isochron user; the
    // other tests (root, in parallel) share it, so its owner and mode come back.
    let iceoryx2 = Path::new("/tmp/iceoryx2");
    let before = std::fs::metadata(iceoryx2).ok();
    let guard = Installed;
    let install = Command::new("dpkg")
        .arg("-i")
        .arg(deb)
        .env("DEBIAN_FRONTEND", "noninteractive")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&install.stdout).into_owned()
        + &String::from_utf8_lossy(&install.stderr);
    if let Some(m) = &before {
        std::os::unix::fs::chown(iceoryx2, Some(m.uid()), Some(m.gid())).unwrap();
        std::fs::set_permissions(iceoryx2, m.permissions()).unwrap();
    }
    assert!(install.status.success(), "dpkg -i: {text}");
    assert!(text.contains("nothing is enabled"), "{text}");

    let user = ok("getent", &["passwd", "isochron"]);
    assert!(user.contains(":/var/lib/isochron:"), "{user}");
    let state = std::fs::metadata("/var/lib/isochron").expect("the state directory");
    let uid: u32 = user.split(':').nth(2).unwrap().parse().unwrap();
    assert_eq!(state.uid(), uid, "/var/lib/isochron belongs to isochron");
    for b in binaries() {
        assert!(Path::new("/usr/bin").join(b).is_file(), "/usr/bin/{b}");
    }
    let version = ok("/usr/bin/isochron", &["--version"]);
    assert_eq!(
        version.trim(),
        format!("isochron {}", env!("CARGO_PKG_VERSION"))
    );
    let capture = ok("/usr/bin/isochron-capture", &["--version"]);
    assert!(capture.starts_with("isochron-capture "), "{capture}");
    // `systemctl is-enabled` reads the unit files; it needs no running systemd.
    let enabled = Command::new("systemctl")
        .arg("is-enabled")
        .args(UNITS)
        .output()
        .unwrap();
    let states = String::from_utf8_lossy(&enabled.stdout).into_owned();
    assert_eq!(states.lines().count(), UNITS.len(), "{states}");
    for (unit, state) in UNITS.iter().zip(states.lines()) {
        assert_eq!(state.trim(), "disabled", "{unit}: {states}");
    }

    let purge = Command::new("dpkg")
        .args(["--purge", "isochron"])
        .output()
        .unwrap();
    assert!(
        purge.status.success(),
        "dpkg --purge: {}",
        String::from_utf8_lossy(&purge.stderr)
    );
    std::mem::forget(guard);
    assert!(!Path::new("/usr/bin/isochron").exists());
    assert!(!Path::new("/usr/lib/systemd/system/isochron.target").exists());
}
