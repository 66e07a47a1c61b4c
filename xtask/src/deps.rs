//! `cargo xtask deps`: the dependency policy, from `cargo metadata` (offline, no
//! advisory database) — what `cargo deny check licenses bans sources` would
//! check, without building cargo-deny on every fresh machine:
//!
//! * **licences**: every crate linked on Linux has an SPDX licence expression
//!   that [`ALLOWED`] satisfies (`OR` takes either side, `AND` needs both);
//! * **sources**: crates.io or a path of this repository (`vendor/`), nothing else;
//! * **duplicates**: a crate in two versions is an error unless it is in
//!   [`KNOWN_DUPLICATES`] (each from upstream crates on two majors).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::Command;

use anyhow::{Context, bail};

/// Licences a dependency may be used under (permissive; MPL-2.0 file-level copyleft
/// is fine for an unmodified dependency).
const ALLOWED: [&str; 16] = [
    "MIT",
    "MIT-0",
    "Apache-2.0",
    "Apache-2.0 WITH LLVM-exception",
    "BSD-2-Clause",
    "BSD-3-Clause",
    "ISC",
    "0BSD",
    "Zlib",
    "Unlicense",
    "CC0-1.0",
    "BSL-1.0",
    "Unicode-3.0",
    "MPL-2.0",
    // Community Data License Agreement, permissive: webpki-roots (Mozilla's CA
    // list, data), which Zenoh's TLS link carries.
    "CDLA-Permissive-2.0",
    // Do What The F*ck You Want To Public License: no conditions at all;
    // ffmpeg-next and ffmpeg-sys-next, the bindings of FFmpeg's libraries.
    "WTFPL",
];

/// The only registry.
const CRATES_IO: &str = "registry+https://github.com/rust-lang/crates.io-index";

/// Crates linked in two versions today, each because upstream crates are on two
/// majors (rand_core 0.6 for RustDDS's crypto, 0.10 for the rest; syn 1 for
/// old derive crates; zenoh 1.10 on rand 0.8, secrecy 0.8 and socket2 0.5, with
/// foldhash through hashbrown 0.15 and spin through two flume; libloading 0.8
/// for clang-sys, OpenCV's bindings' build, 0.9 for ort's `load-dynamic`; …). A
/// new name here needs a reason; removing one that no longer doubles is welcome
/// (the check says which).
const KNOWN_DUPLICATES: [&str; 36] = [
    "base64",
    "bitflags",
    "block-buffer",
    "const-oid",
    "cpufeatures",
    "crypto-common",
    "darling",
    "darling_core",
    "darling_macro",
    "der",
    "digest",
    "embedded-io",
    "flume",
    "foldhash",
    "getrandom",
    "hashbrown",
    "indexmap",
    "itertools",
    "libloading",
    "miniz_oxide",
    "nom",
    "rand",
    "rand_core",
    "rustls-webpki",
    "schemars",
    "secrecy",
    "shlex",
    "socket2",
    "spin",
    "spki",
    "syn",
    "thiserror",
    "thiserror-impl",
    "toml",
    "toml_datetime",
    "winnow",
];

/// Checks the policy on the workspace at `root`.
pub(crate) fn check(root: &Path) -> anyhow::Result<()> {
    let out = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
        .args(["metadata", "--format-version", "1", "--locked", "--offline"])
        .args(["--filter-platform", "x86_64-unknown-linux-gnu"])
        .current_dir(root)
        .output()
        .context("running cargo metadata")?;
    if !out.status.success() {
        bail!("cargo metadata: {}", String::from_utf8_lossy(&out.stderr));
    }
    let meta: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    let linked: BTreeSet<&str> = meta["resolve"]["nodes"]
        .as_array()
        .context("cargo metadata: no resolve")?
        .iter()
        .filter_map(|n| n["id"].as_str())
        .collect();
    let mut problems = Vec::new();
    let mut versions: BTreeMap<&str, BTreeSet<&str>> = BTreeMap::new();
    let mut from_path = 0;
    for p in meta["packages"]
        .as_array()
        .context("cargo metadata: no packages")?
    {
        if !p["id"].as_str().is_some_and(|id| linked.contains(id)) {
            continue;
        }
        let name = p["name"].as_str().unwrap_or("?");
        let version = p["version"].as_str().unwrap_or("?");
        versions.entry(name).or_default().insert(version);
        match p["source"].as_str() {
            None => from_path += 1,
            Some(CRATES_IO) => {}
            Some(other) => problems.push(format!("{name} {version}: from {other}")),
        }
        let workspace_tool = p["source"].is_null() && name == "xtask";
        match p["license"].as_str() {
            Some(expr) => match allowed(expr) {
                Ok(true) => {}
                Ok(false) => problems.push(format!("{name} {version}: licence {expr} not allowed")),
                Err(e) => problems.push(format!("{name} {version}: licence {expr:?}: {e}")),
            },
            None if workspace_tool => {}
            None => problems.push(format!("{name} {version}: no licence")),
        }
    }
    let doubled: Vec<&str> = (versions.iter())
        .filter(|(_, v)| v.len() > 1)
        .map(|(n, _)| *n)
        .collect();
    for name in doubled.iter().filter(|n| !KNOWN_DUPLICATES.contains(n)) {
        problems.push(format!(
            "{name} in versions {:?}: align the dependants, or add it to KNOWN_DUPLICATES with a reason",
            versions[name]
        ));
    }
    let gone: Vec<&str> = (KNOWN_DUPLICATES.iter().copied())
        .filter(|n| !doubled.contains(n))
        .collect();
    if !problems.is_empty() {
        bail!(
            "dependency policy (xtask/src/deps.rs):\n  {}",
            problems.join("\n  ")
        );
    }
    eprintln!(
        "xtask: deps: {} crates ({} from crates.io, {from_path} of this repository), every licence allowed, {} in two versions (all known{})",
        linked.len(),
        linked.len() - from_path,
        doubled.len(),
        if gone.is_empty() {
            String::new()
        } else {
            format!(
                "; no longer doubled, remove from KNOWN_DUPLICATES: {}",
                gone.join(", ")
            )
        }
    );
    Ok(())
}

/// True if [`ALLOWED`] satisfies the SPDX expression `expr` (`/` read as `OR`,
/// as old manifests write it).
fn allowed(expr: &str) -> Result<bool, String> {
    let spaced = expr
        .replace('/', " OR ")
        .replace('(', " ( ")
        .replace(')', " ) ");
    let tokens: Vec<&str> = spaced.split_whitespace().collect();
    let mut at = 0;
    let ok = or_expr(&tokens, &mut at)?;
    if at != tokens.len() {
        return Err(format!("unexpected {:?}", tokens[at]));
    }
    Ok(ok)
}

fn or_expr(t: &[&str], at: &mut usize) -> Result<bool, String> {
    let mut ok = and_expr(t, at)?;
    while t.get(*at) == Some(&"OR") {
        *at += 1;
        ok |= and_expr(t, at)?;
    }
    Ok(ok)
}

fn and_expr(t: &[&str], at: &mut usize) -> Result<bool, String> {
    let mut ok = licence(t, at)?;
    while t.get(*at) == Some(&"AND") {
        *at += 1;
        ok &= licence(t, at)?;
    }
    Ok(ok)
}

fn licence(t: &[&str], at: &mut usize) -> Result<bool, String> {
    match t.get(*at) {
        Some(&"(") => {
            *at += 1;
            let ok = or_expr(t, at)?;
            if t.get(*at) != Some(&")") {
                return Err("a ( without )".into());
            }
            *at += 1;
            Ok(ok)
        }
        Some(id) if !matches!(*id, ")" | "AND" | "OR" | "WITH") => {
            *at += 1;
            let mut name = id.to_string();
            if t.get(*at) == Some(&"WITH") {
                let exception = t.get(*at + 1).ok_or("WITH what?")?;
                name = format!("{name} WITH {exception}");
                *at += 2;
            }
            Ok(ALLOWED.contains(&name.as_str()))
        }
        other => Err(format!("expected a licence, found {other:?}")),
    }
}

#[cfg(test)]
mod tests {
    use super::allowed;

    #[test]
    fn spdx_expressions() {
        assert_eq!(allowed("MIT OR Apache-2.0"), Ok(true));
        assert_eq!(allowed("MIT/Apache-2.0"), Ok(true));
        assert_eq!(allowed("(MIT OR Apache-2.0) AND Unicode-3.0"), Ok(true));
        assert_eq!(
            allowed("Apache-2.0 WITH LLVM-exception OR GPL-3.0"),
            Ok(true)
        );
        assert_eq!(allowed("GPL-3.0"), Ok(false));
        assert_eq!(allowed("MIT AND GPL-2.0"), Ok(false));
        assert_eq!(allowed("GPL-2.0 OR (MIT AND ISC)"), Ok(true));
        assert!(allowed("(MIT").is_err());
        assert!(allowed("MIT OR").is_err());
    }
}
