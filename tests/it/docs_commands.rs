//! Every `isochron …` command the docs show, tried as a newcomer pastes it:
//! each command line of a code block of README.md and docs/*.md, and each
//! `isochron …` span of their prose. Every subcommand must exist and every
//! `--flag` be one of its own (`isochron … --help` says which); the command
//! lines that need no running group, no root and no network are run, in a
//! working directory with the repository's `config/` and `data/`, and must end
//! with a code of the exit table — never 101 (a panic) nor 2 (clap refused the
//! line).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use isochron_tests::{Proc, bin, repo_root};

/// The exit table (docs/operating.md, "Exit codes"), without clap's 2.
const TABLE: [i32; 11] = [0, 1, 3, 64, 65, 66, 69, 70, 75, 78, 130];

/// Subcommands that need the running group (or run until stopped), root, or
/// the network, or take minutes: checked, not run.
const NOT_RUN: [&str; 9] = [
    "up",
    "status",
    "tap",
    "view",
    "record",
    "plan now",
    "plan graph",
    "keystore",
    "costmap snapshot",
];

/// A documented command: where, and its words after `isochron`.
#[derive(Debug)]
struct Documented {
    at: String,
    words: Vec<String>,
    /// From a code block (a line to paste), not from prose.
    pasted: bool,
}

/// The words of a shell line: split at blanks outside quotes, quotes removed, a
/// trailing `# comment` dropped.
fn words(line: &str) -> Vec<String> {
    let (mut out, mut word, mut quote, mut has) = (Vec::new(), String::new(), None, false);
    for c in line.chars() {
        match (quote, c) {
            (None, '#') if !has => break,
            (None, '\'' | '"') => (quote, has) = (Some(c), true),
            (Some(q), c) if c == q => quote = None,
            (None, c) if c.is_whitespace() => {
                if has {
                    out.push(std::mem::take(&mut word));
                }
                has = false;
            }
            (_, c) => (word, has) = (word + &c.to_string(), true),
        }
    }
    if has {
        out.push(word);
    }
    out
}

/// The words after `isochron` of `text`, if it is an isochron command line
/// (`isochron …`, `target/debug/isochron …`, `sudo -u isochron isochron …`).
fn command_words(text: &str) -> Option<Vec<String>> {
    let all = words(text);
    let at = all
        .iter()
        .position(|w| w == "isochron" || w.ends_with("/isochron"))?;
    // `sudo -u isochron isochron …`: the user, then the command.
    let at = match all.get(at + 1) {
        Some(next)
            if all.get(at.wrapping_sub(1)).is_some_and(|p| p == "-u") && next == "isochron" =>
        {
            at + 1
        }
        _ => at,
    };
    let lead_ok = all[..at]
        .iter()
        .all(|w| matches!(w.as_str(), "sudo" | "-u" | "isochron") || w.contains('='));
    (lead_ok && at + 1 < all.len()).then(|| all[at + 1..].to_vec())
}

/// Every documented command of README.md and docs/*.md.
fn documented() -> Vec<Documented> {
    let root = repo_root();
    let mut files = vec![root.join("README.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
        .unwrap()
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    docs.sort();
    files.extend(docs);
    let mut found = Vec::new();
    for file in files {
        let name = file.strip_prefix(&root).unwrap().display().to_string();
        let text = std::fs::read_to_string(&file).unwrap();
        let mut in_block = false;
        for (i, line) in text.lines().enumerate() {
            let at = format!("{name}:{}", i + 1);
            if line.trim_start().starts_with("```") {
                in_block = !in_block;
                continue;
            }
            if in_block {
                if let Some(words) = command_words(line) {
                    found.push(Documented {
                        at,
                        words,
                        pasted: true,
                    });
                }
                continue;
            }
            // `isochron …` spans of the prose.
            for span in line.split('`').skip(1).step_by(2) {
                if span.starts_with("isochron ")
                    && let Some(words) = command_words(span)
                {
                    found.push(Documented {
                        at: at.clone(),
                        words,
                        pasted: false,
                    });
                }
            }
        }
    }
    found
}

/// `isochron PATH --help`, memoised.
fn help<'a>(cache: &'a mut BTreeMap<Vec<String>, String>, path: &[String]) -> &'a str {
    cache.entry(path.to_vec()).or_insert_with(|| {
        let mut args: Vec<&str> = path.iter().map(String::as_str).collect();
        args.push("--help");
        let out = std::process::Command::new(bin("isochron"))
            .args(&args)
            .output()
            .unwrap();
        assert!(out.status.success(), "isochron {args:?} failed");
        String::from_utf8_lossy(&out.stdout).into_owned()
    })
}

/// The subcommands a help text lists.
fn subcommands(help: &str) -> Vec<String> {
    let Some(start) = help.find("Commands:") else {
        return Vec::new();
    };
    help[start..]
        .lines()
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next().map(str::to_string))
        .collect()
}

/// The flags a word names: `--a`, `[--a`, `--a=1`, `--a/--b`, `--a]]`.
fn flags_of(word: &str) -> Vec<String> {
    word.split('/')
        .map(|w| w.trim_start_matches('['))
        .filter(|w| w.starts_with("--"))
        .map(|w| {
            w.split(['=', ']', ',', '|', ')', '.'])
                .next()
                .unwrap_or(w)
                .to_string()
        })
        .collect()
}

/// The subcommand path of `words` (checked against the help texts) and what is
/// wrong with the command, if anything.
fn check(
    cache: &mut BTreeMap<Vec<String>, String>,
    words: &[String],
) -> (Vec<String>, Vec<String>) {
    let mut path: Vec<String> = Vec::new();
    let mut wrong = Vec::new();
    for word in words {
        let listed = subcommands(help(cache, &path));
        // A flag, an optional part or a placeholder (`<command>`) ends the path.
        if word.starts_with(['-', '[', '<']) || listed.is_empty() {
            break;
        }
        if listed.contains(word) {
            path.push(word.clone());
        } else {
            wrong.push(format!(
                "no subcommand '{word}' of 'isochron {}'",
                path.join(" ")
            ));
            return (path, wrong);
        }
    }
    let text = help(cache, &path).to_string();
    for flag in words.iter().flat_map(|w| flags_of(w)) {
        let known = text.match_indices(&flag).any(|(i, _)| {
            !text[i + flag.len()..].starts_with(|c: char| c.is_alphanumeric() || c == '-')
        });
        if !known && flag != "--help" {
            wrong.push(format!("'isochron {}' has no flag {flag}", path.join(" ")));
        }
    }
    (path, wrong)
}

/// The line to run for a pasted command: its optional parts (`[...]`) left out
/// and the docs' stand-ins given the demo's files; `None` if a placeholder is
/// left (`DIR`, `...`, `<box_id>`).
fn runnable(words: &[String], work: &Path) -> Option<Vec<String>> {
    let mut depth = 0i32;
    let mut out = Vec::new();
    for w in words {
        let opens = w.matches('[').count() as i32;
        let closes = w.matches(']').count() as i32;
        if depth == 0 && opens == 0 {
            out.push(w.clone());
        }
        depth += opens - closes;
    }
    let stand_in = |w: &str| -> String {
        match w {
            "site.toml" => "config/demo.toml".into(),
            "video.avi" => "data/vtest.avi".into(),
            "DIR" => work.join("out/dir").display().to_string(),
            "HH:MM" => "16:30".into(),
            "FILE.png" | "OUT.png" => "out/picture.png".into(),
            other => other.to_string(),
        }
    };
    let out: Vec<String> = out.iter().map(|w| stand_in(w)).collect();
    let placeholder = |w: &String| {
        w.contains("...")
            || w.contains('<')
            || w.contains('|')
            || (w.len() > 1
                && w.chars()
                    .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_'))
    };
    (!out.iter().any(placeholder)).then_some(out)
}

#[test]
fn every_documented_isochron_command_exists_and_pastes() {
    let commands = documented();
    assert!(
        commands.len() > 40,
        "found only {} commands",
        commands.len()
    );
    let work = tempfile::Builder::new()
        .prefix("isochron-docs-")
        .tempdir()
        .unwrap();
    // A copy of config/ (its state_dir, ../out/state, is then the work dir's),
    // the sample data read in place.
    let copied = std::process::Command::new("cp")
        .arg("-r")
        .arg(repo_root().join("config"))
        .arg(work.path())
        .status()
        .unwrap();
    assert!(copied.success());
    std::os::unix::fs::symlink(repo_root().join("data"), work.path().join("data")).unwrap();
    std::fs::create_dir(work.path().join("out")).unwrap();
    let mut cache = BTreeMap::new();
    let mut wrong = Vec::new();
    let mut ran = 0;
    for c in &commands {
        let (path, problems) = check(&mut cache, &c.words);
        wrong.extend(problems.iter().map(|p| format!("{}: {p}", c.at)));
        let joined = path.join(" ");
        let skip = NOT_RUN
            .iter()
            .any(|n| joined == *n || joined.starts_with(&format!("{n} ")))
            || (matches!(joined.as_str(), "synth" | "doctor")
                && c.words.iter().any(|w| w == "--fix" || w == "--days"));
        if !c.pasted || !problems.is_empty() || skip {
            continue;
        }
        let Some(line) = runnable(&c.words, work.path()) else {
            continue;
        };
        let mut proc = Proc::spawn_in(&bin("isochron"), &line, Some(work.path()));
        let status = proc.wait(Duration::from_secs(180));
        ran += 1;
        let code = status.and_then(|s| s.code());
        let stderr = proc.stderr();
        match code {
            Some(code) if TABLE.contains(&code) && !stderr.contains("panicked") => {}
            _ => wrong.push(format!(
                "{}: isochron {line:?} ended with {code:?}:\n{stderr}",
                c.at
            )),
        }
    }
    eprintln!("{} documented commands checked, {ran} run", commands.len());
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
    assert!(ran >= 5, "only {ran} commands ran");
}
