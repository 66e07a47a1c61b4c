//! `cargo xtask structure`: the layout rules clippy cannot check, over the Rust
//! files git tracks (not `vendor/`):
//!
//! * no file longer than [`MAX_LINES`] lines, tests excepted (`tests.rs` modules,
//!   `tests/it/`, a crate's `tests/`): a longer file is several jobs;
//! * no cycle among a crate's modules: module `a` uses `b` when its code names a
//!   path `crate::b…`, `super::b…` or `self::b…` (an item re-exported elsewhere
//!   counts for the module that defines it); a module and its own ancestors or
//!   descendants do not count, nor do test modules.
//!
//! It reads the files as text (no parser): a path in a string counts as a use.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::Path;
use std::process::Command;

use anyhow::{Context, bail};

use crate::output;

/// The longest a file that is not a test may be, lines.
pub(crate) const MAX_LINES: usize = 700;

/// A module, as the path of names below its crate root (empty: the root).
type Module = Vec<String>;

/// Checks both rules; the error lists every file too long and every cycle.
pub(crate) fn check(root: &Path) -> anyhow::Result<()> {
    let listed = output(
        Command::new("git")
            .arg("-C")
            .arg(root)
            .args(["ls-files", "*.rs"]),
    )?;
    let files: Vec<&str> = listed
        .lines()
        .filter(|f| !f.starts_with("vendor/"))
        .collect();
    let mut texts = BTreeMap::new();
    for &file in &files {
        let text =
            std::fs::read_to_string(root.join(file)).with_context(|| format!("reading {file}"))?;
        texts.insert(file, text);
    }
    let mut problems = Vec::new();
    for (file, text) in &texts {
        let lines = text.lines().count();
        if lines > MAX_LINES && !is_test(file) {
            problems.push(format!(
                "{file}: {lines} lines (at most {MAX_LINES}): split it by job into modules"
            ));
        }
    }
    for (src, modules) in crates(&texts) {
        for cycle in cycles(&uses(&modules)) {
            let names: Vec<String> = cycle.iter().map(name).collect();
            problems.push(format!(
                "{src}: the modules {} use each other: move what they share to the one \
                 that owns it, or to a module of its own",
                names.join(", ")
            ));
        }
    }
    if !problems.is_empty() {
        bail!("structure:\n  {}", problems.join("\n  "));
    }
    eprintln!(
        "xtask: structure: {} files, none over {MAX_LINES} lines but tests, no module cycles",
        files.len()
    );
    Ok(())
}

/// True for a file of tests: a `tests.rs` module, `tests/it/`, a crate's `tests/`.
fn is_test(file: &str) -> bool {
    file.ends_with("/tests.rs") || file.starts_with("tests/it/") || file.contains("/tests/")
}

/// The modules of every crate: by its `src` directory, each module's text without
/// its in-file test module. Binaries under `src/bin/`, a `main.rs` beside a
/// `lib.rs`, and test modules are left out.
fn crates<'a>(texts: &'a BTreeMap<&str, String>) -> BTreeMap<&'a str, HashMap<Module, &'a str>> {
    let mut out: BTreeMap<&str, HashMap<Module, &str>> = BTreeMap::new();
    for (file, text) in texts {
        let Some(at) = file
            .find("src/")
            .filter(|&i| i == 0 || file[..i].ends_with('/'))
        else {
            continue;
        };
        let (src, rel) = (&file[..at + 3], &file[at + 4..]);
        let mut path: Module = rel
            .trim_end_matches(".rs")
            .split('/')
            .map(String::from)
            .collect();
        if path.first().is_some_and(|p| p == "bin")
            || path.last().is_some_and(|p| p == "tests")
            || (rel == "main.rs" && texts.contains_key(format!("{src}/lib.rs").as_str()))
        {
            continue;
        }
        if path
            .last()
            .is_some_and(|p| ["lib", "main", "mod"].contains(&p.as_str()))
        {
            path.pop();
        }
        let code = text
            .split("#[cfg(test)]\nmod tests {")
            .next()
            .unwrap_or(text);
        out.entry(src).or_default().insert(path, code);
    }
    out
}

/// Which module uses which (edges to ancestors and descendants left out).
fn uses(modules: &HashMap<Module, &str>) -> BTreeMap<Module, BTreeSet<Module>> {
    let defined = definitions(modules);
    let mut edges: BTreeMap<Module, BTreeSet<Module>> = BTreeMap::new();
    for (module, code) in modules {
        for path in paths(module, code) {
            let target = resolve(modules, &defined, &path);
            if !target.starts_with(module) && !module.starts_with(&target) {
                edges.entry(module.clone()).or_default().insert(target);
            }
        }
        edges.entry(module.clone()).or_default();
    }
    edges
}

/// The modules that define each public name (`pub struct Name`, `pub(crate) fn
/// name`, …).
fn definitions(modules: &HashMap<Module, &str>) -> HashMap<String, BTreeSet<Module>> {
    let mut out: HashMap<String, BTreeSet<Module>> = HashMap::new();
    for (module, code) in modules {
        for line in code.lines() {
            let Some(rest) = line.trim_start().strip_prefix("pub") else {
                continue;
            };
            let rest = match rest.strip_prefix('(') {
                Some(r) => r.split_once(')').map_or("", |(_, r)| r),
                None => rest,
            };
            let mut words = rest
                .split_whitespace()
                .skip_while(|w| ["unsafe", "async", "extern", "\"C\""].contains(w));
            let (Some(kind), Some(mut name)) = (words.next(), words.next()) else {
                continue;
            };
            if kind == "const" && name == "fn" {
                name = words.next().unwrap_or("");
            } else if ![
                "struct", "enum", "fn", "trait", "type", "const", "static", "mod",
            ]
            .contains(&kind)
            {
                continue;
            }
            let name: String = name.chars().take_while(|c| is_ident(*c)).collect();
            out.entry(name).or_default().insert(module.clone());
        }
    }
    out
}

/// The module a path names (from the crate root): the longest of its prefixes
/// that is a module, or, for an item that module only re-exports, the one module
/// that defines it.
fn resolve(
    modules: &HashMap<Module, &str>,
    defined: &HashMap<String, BTreeSet<Module>>,
    path: &[String],
) -> Module {
    for n in (0..=path.len()).rev() {
        let prefix = path[..n].to_vec();
        if !modules.contains_key(&prefix) {
            continue;
        }
        if let Some(item) = path.get(n)
            && let Some(owners) = defined.get(item)
            && owners.len() == 1
            && !owners.contains(&prefix)
        {
            return owners.iter().next().cloned().unwrap_or(prefix);
        }
        return prefix;
    }
    Vec::new()
}

/// Every path `crate::…`, `super::…` or `self::…` in `code` of `module`, from the
/// crate root; a group (`crate::a::{b, c::D}`) gives one path per member.
fn paths(module: &Module, code: &str) -> Vec<Vec<String>> {
    let code: String = code
        .lines()
        .map(|l| l.split_once("//").map_or(l, |(code, _)| code))
        .collect::<Vec<_>>()
        .join("\n");
    let chars: Vec<char> = code.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        let starts_word = i == 0 || !is_ident(chars[i - 1]) && chars[i - 1] != ':';
        let word: String = chars[i..].iter().take_while(|c| is_ident(**c)).collect();
        if !starts_word || word.is_empty() {
            i += 1;
            continue;
        }
        i += word.len();
        let mut base = match word.as_str() {
            "crate" => Vec::new(),
            "self" => module.clone(),
            "super" => module[..module.len().saturating_sub(1)].to_vec(),
            _ => continue,
        };
        while chars[i..].starts_with(&[':', ':', 's', 'u', 'p', 'e', 'r', ':', ':']) {
            base.pop();
            i += 7;
        }
        if chars[i..].starts_with(&[':', ':']) {
            i += 2;
            tree(&chars, &mut i, base, &mut out);
        }
    }
    out
}

/// Reads a use tree at `chars[*i]` below `prefix` into `out`.
fn tree(chars: &[char], i: &mut usize, mut prefix: Vec<String>, out: &mut Vec<Vec<String>>) {
    loop {
        while chars.get(*i).is_some_and(|c| c.is_whitespace()) {
            *i += 1;
        }
        if chars.get(*i) == Some(&'{') {
            *i += 1;
            loop {
                tree(chars, i, prefix.clone(), out);
                while chars
                    .get(*i)
                    .is_some_and(|c| c.is_whitespace() || *c == ',')
                {
                    *i += 1;
                }
                match chars.get(*i) {
                    Some('}') => {
                        *i += 1;
                        return;
                    }
                    Some(c) if is_ident(*c) || *c == '{' => {}
                    _ => return,
                }
            }
        }
        let word: String = chars[*i..].iter().take_while(|c| is_ident(**c)).collect();
        if word.is_empty() {
            out.push(prefix);
            return;
        }
        *i += word.len();
        if word != "self" {
            prefix.push(word);
        }
        if chars[*i..].starts_with(&[':', ':']) {
            *i += 2;
        } else {
            out.push(prefix);
            return;
        }
    }
}

fn is_ident(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// The cycles of `edges`: its strongly connected components of more than one
/// module (Tarjan's algorithm).
fn cycles(edges: &BTreeMap<Module, BTreeSet<Module>>) -> Vec<Vec<Module>> {
    struct Search<'a> {
        edges: &'a BTreeMap<Module, BTreeSet<Module>>,
        index: HashMap<&'a Module, (usize, usize)>,
        stack: Vec<&'a Module>,
        found: Vec<Vec<Module>>,
    }
    fn visit<'a>(s: &mut Search<'a>, v: &'a Module) {
        let n = s.index.len();
        s.index.insert(v, (n, n));
        s.stack.push(v);
        for w in s.edges.get(v).into_iter().flatten() {
            let low = match s.index.get(w) {
                None if s.edges.contains_key(w) => {
                    visit(s, w);
                    s.index[w].1
                }
                Some(&(index, _)) if s.stack.contains(&w) => index,
                _ => continue,
            };
            let entry = s.index.get_mut(v).expect("visited above");
            entry.1 = entry.1.min(low);
        }
        if s.index[v].0 == s.index[v].1 {
            let at = s.stack.iter().rposition(|m| *m == v).expect("on the stack");
            let component: Vec<Module> = s.stack.drain(at..).cloned().collect();
            if component.len() > 1 {
                s.found.push(component);
            }
        }
    }
    let mut search = Search {
        edges,
        index: HashMap::new(),
        stack: Vec::new(),
        found: Vec::new(),
    };
    for v in edges.keys() {
        if !search.index.contains_key(v) {
            visit(&mut search, v);
        }
    }
    search.found
}

/// `a::b`, or `crate` for the root.
fn name(module: &Module) -> String {
    if module.is_empty() {
        "crate".into()
    } else {
        module.join("::")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn module(path: &str) -> Module {
        path.split("::")
            .filter(|s| !s.is_empty())
            .map(String::from)
            .collect()
    }

    #[test]
    fn paths_of_uses_groups_and_calls() {
        let code = "use crate::a::{B, c::{D, self}};\nuse super::e;\nfn f() { crate::g::h(); }";
        let found = paths(&module("x::y"), code);
        let expected: Vec<Module> = ["a::B", "a::c::D", "a::c", "x::e", "g::h"]
            .into_iter()
            .map(module)
            .collect();
        assert_eq!(found, expected);
    }

    #[test]
    fn a_cycle_of_siblings_is_found_and_parent_child_is_not() {
        let modules: HashMap<Module, &str> = [
            ("", "mod a; mod b; pub use a::Thing;"),
            ("a", "pub struct Thing; use crate::b::f;"),
            ("b", "pub fn f() {} fn g(_: crate::Thing) {}"),
            ("c", "use super::a::Thing;"),
        ]
        .into_iter()
        .map(|(m, code)| (module(m), code))
        .collect();
        let found = cycles(&uses(&modules));
        assert_eq!(found.len(), 1, "{found:?}");
        let mut names: Vec<String> = found[0].iter().map(name).collect();
        names.sort();
        assert_eq!(names, ["a", "b"]);
    }

    #[test]
    fn tests_are_exempt_from_the_length_rule() {
        assert!(is_test("services/cascade/src/tests.rs"));
        assert!(is_test("tests/it/costmap.rs"));
        assert!(is_test("services/motion/tests/no_alloc.rs"));
        assert!(!is_test("tests/harness.rs"));
        assert!(!is_test("tests/benches/group.rs"));
    }
}
