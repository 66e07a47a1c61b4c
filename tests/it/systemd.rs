//! The systemd units: every unit passes `systemd-analyze verify`, and each service's
//! `systemd-analyze security --offline=yes` exposure is at most 2.0.
//!
//! The units are checked as `cargo xtask install` installs them: copied with the
//! shared drop-in, `/usr/bin/` pointing at the built binaries.

use std::path::Path;
use std::process::Command;

use isochron_tests::{bin_dir, repo_root};

const SERVICES: [&str; 8] = [
    "isochron-capture@cam01.service",
    "isochron-motion@cam01.service",
    "isochron-cascade@cam01.service",
    "isochron-gate@cam01.service",
    "isochron-costmap.service",
    "isochron-exporter.service",
    "isochron-link.service",
    "isochron-mqtt.service",
];

/// Copies `systemd/` into `dir` with binaries pointing at the build.
fn install_units(dir: &Path) {
    let bin = format!("{}/", bin_dir().display());
    let copy = |from: &Path, to: &Path| {
        let text = std::fs::read_to_string(from)
            .unwrap()
            .replace("/usr/bin/", &bin);
        std::fs::write(to, text).unwrap();
    };
    for entry in std::fs::read_dir(repo_root().join("systemd")).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap();
        if path.is_dir() {
            std::fs::create_dir_all(dir.join(name)).unwrap();
            for inner in std::fs::read_dir(&path).unwrap() {
                let inner = inner.unwrap().path();
                copy(&inner, &dir.join(name).join(inner.file_name().unwrap()));
            }
        } else if path
            .extension()
            .is_some_and(|e| e == "service" || e == "target")
        {
            copy(&path, &dir.join(name));
        }
    }
}

fn analyze(dir: &Path, args: &[&str]) -> (bool, String) {
    let out = Command::new("systemd-analyze")
        .args(args)
        // A trailing ':' keeps the system's own unit directories (for targets
        // such as network-online.target).
        .env("SYSTEMD_UNIT_PATH", format!("{}:", dir.display()))
        .output()
        .expect("systemd-analyze is installed (package systemd; cargo xtask setup)");
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    (out.status.success(), text)
}

#[test]
fn every_unit_verifies() {
    let dir = tempfile::tempdir().unwrap();
    install_units(dir.path());
    for unit in SERVICES.iter().chain(&["isochron.target"]) {
        let (ok, text) = analyze(dir.path(), &["verify", unit]);
        assert!(ok && text.trim().is_empty(), "{unit}: {text}");
    }
}

#[test]
fn every_service_is_hardened_to_an_exposure_of_at_most_2() {
    let dir = tempfile::tempdir().unwrap();
    install_units(dir.path());
    for unit in SERVICES {
        let (_, text) = analyze(dir.path(), &["security", "--offline=yes", unit]);
        let level: f64 = text
            .lines()
            .find_map(|l| l.split("Overall exposure level for ").nth(1))
            .and_then(|rest| rest.split(':').nth(1))
            .and_then(|v| v.split_whitespace().next())
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("{unit}: no exposure level in\n{text}"));
        println!("{unit}: exposure {level}");
        assert!(level <= 2.0, "{unit}: exposure {level} > 2.0\n{text}");
    }
}

/// What `systemd-analyze security --offline=yes` says `unit` really gets, line by
/// line: `(setting, secure)` where secure is its ✓ / ✗ mark.
fn effective(dir: &Path, unit: &str) -> Vec<(String, bool)> {
    let (_, text) = analyze(dir, &["security", "--offline=yes", unit]);
    text.lines()
        .filter_map(|l| {
            let l = l.trim_start();
            let (secure, rest) = if let Some(r) = l.strip_prefix('✓') {
                (true, r)
            } else {
                (false, l.strip_prefix('✗')?)
            };
            Some((rest.split_whitespace().next()?.to_string(), secure))
        })
        .collect()
}

#[test]
fn each_service_gets_the_access_it_needs_and_no_more() {
    let dir = tempfile::tempdir().unwrap();
    install_units(dir.path());
    // (setting, secure?) as the analyser reports it, after every drop-in applied.
    let expect = |unit: &str, settings: &[(&str, bool)]| {
        let got = effective(dir.path(), unit);
        for (setting, secure) in settings {
            let found = got.iter().find(|(s, _)| s == setting);
            assert_eq!(
                found.map(|(_, s)| *s),
                Some(*secure),
                "{unit}: {setting} should be {}; the analyser says {got:?}",
                if *secure { "locked down" } else { "open" }
            );
        }
    };
    // Capture reads V4L2 devices and network cameras: the shared hardening must not
    // win over its exceptions.
    let capture = [
        ("PrivateDevices=", false),
        ("PrivateUsers=", false),
        ("IPAddressDeny=", false),
        ("RestrictAddressFamilies=~AF_(INET|INET6)", false),
        ("NoNewPrivileges=", true),
    ];
    // The bridge talks DDS over the network, and needs no device.
    let bridge = [
        ("PrivateDevices=", true),
        ("IPAddressDeny=", false),
        ("RestrictAddressFamilies=~AF_(INET|INET6)", false),
        ("NoNewPrivileges=", true),
    ];
    // The exporter serves HTTP to this machine only (an allow list, which the
    // analyser marks as open), the MQTT sink connects to its broker (this machine
    // only unless a drop-in allows more), the link talks DDS to the other boxes;
    // none needs a device.
    let networked = [
        ("PrivateDevices=", true),
        ("PrivateUsers=", true),
        ("IPAddressDeny=", false),
        ("RestrictAddressFamilies=~AF_(INET|INET6)", false),
        ("NoNewPrivileges=", true),
    ];
    // The others need neither devices nor the network.
    let isolated = [
        ("PrivateDevices=", true),
        ("PrivateUsers=", true),
        ("IPAddressDeny=", true),
        ("RestrictAddressFamilies=~AF_(INET|INET6)", true),
    ];
    for (unit, settings) in [
        ("isochron-capture@cam01.service", &capture[..]),
        ("isochron-costmap.service", &bridge),
        ("isochron-exporter.service", &networked),
        ("isochron-mqtt.service", &networked),
        ("isochron-link.service", &networked),
        ("isochron-motion@cam01.service", &isolated),
        ("isochron-cascade@cam01.service", &isolated),
        ("isochron-gate@cam01.service", &isolated),
    ] {
        expect(unit, settings);
    }
}

#[test]
fn services_share_hardening_readiness_and_restart_policy() {
    let dropin =
        std::fs::read_to_string(repo_root().join("systemd/isochron-.service.d/10-hardening.conf"))
            .unwrap();
    for line in [
        "Type=notify",
        "WatchdogSec=",
        "Restart=on-failure",
        "RestartPreventExitStatus=64 65 66 78",
        "User=isochron",
        "NoNewPrivileges=yes",
        "ProtectSystem=strict",
        "ProtectHome=yes",
        "ReadWritePaths=/dev/shm -/tmp/iceoryx2",
    ] {
        assert!(dropin.contains(line), "the shared drop-in lacks {line}");
    }
    assert!(
        !dropin.contains("PrivateTmp=yes"),
        "services must share /tmp/iceoryx2"
    );
    for unit in SERVICES {
        let file = unit.replace("@cam01", "@");
        let text = std::fs::read_to_string(repo_root().join("systemd").join(&file)).unwrap();
        assert!(text.contains("PartOf=isochron.target"), "{file}");
        assert!(text.contains("WantedBy=isochron.target"), "{file}");
    }
}
