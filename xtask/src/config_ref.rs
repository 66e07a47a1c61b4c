//! `cargo xtask docs config [--check]`: the configuration reference,
//! `docs/configuration.md`, generated so that it cannot drift from the code.
//!
//! * **Keys, types and descriptions** come from the config structs' source,
//!   `shared/config/src/*.rs`, parsed with `syn`: every `[section]` is a struct
//!   reached from `Config`'s fields, every key a field, its description the field's
//!   doc comment, its name serde's (`rename`), its type the field's Rust type. A
//!   field without a doc comment, or of a type the generator cannot name, is an
//!   error.
//! * **Defaults** are the real ones: the `isochron-config-defaults` example of the
//!   config crate prints the configuration serde makes of a file that sets only
//!   what has no default, as JSON. A doc comment that says `Default <value>` is
//!   checked against it, so prose and code cannot disagree either.
//!
//! `--check` writes nothing and fails when the file on disk differs from what
//! would be written; `cargo xtask test` (and so CI) runs it.

use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use anyhow::{Context, bail};
use serde_json::Value;

/// Where the reference is written, relative to the repository.
pub const OUTPUT: &str = "docs/configuration.md";

/// The example of `isochron-config` that prints the defaults.
const DEFAULTS_EXAMPLE: &str = "isochron-config-defaults";

/// Types whose TOML form serde does not derive: how the reference names them.
/// The generator fails on a type it meets that is neither here nor derivable, so
/// a new one is named here once.
const CUSTOM_TYPES: [(&str, &str); 1] = [("Speed", "`\"max\"` or number")];

/// `cargo xtask docs config [--check]`; `cargo` builds the defaults example.
pub fn run(root: &Path, cargo: Command, args: &[String]) -> anyhow::Result<()> {
    match args {
        [] => {
            let text = generate(root, cargo)?;
            std::fs::write(root.join(OUTPUT), text).with_context(|| format!("writing {OUTPUT}"))?;
            eprintln!("xtask: wrote {OUTPUT}");
            Ok(())
        }
        [flag] if flag == "--check" => check(root, cargo),
        _ => bail!("usage: cargo xtask docs config [--check]"),
    }
}

/// Fails unless `docs/configuration.md` is what the generator writes.
pub fn check(root: &Path, cargo: Command) -> anyhow::Result<()> {
    let want = generate(root, cargo)?;
    let have = std::fs::read_to_string(root.join(OUTPUT)).unwrap_or_default();
    if have == want {
        eprintln!("xtask: {OUTPUT} is up to date");
        return Ok(());
    }
    let line = have
        .lines()
        .zip(want.lines())
        .position(|(a, b)| a != b)
        .unwrap_or_else(|| have.lines().count().min(want.lines().count()))
        + 1;
    bail!(
        "{OUTPUT} is stale (it differs from line {line} on): run `cargo xtask docs config` and commit it"
    )
}

/// The whole reference.
fn generate(root: &Path, cargo: Command) -> anyhow::Result<String> {
    let defaults = defaults(cargo)?;
    let source = Source::read(&root.join("shared/config/src"))?;
    let mut sections = Vec::new();
    source.sections("Config", "", false, None, Some(&defaults), &mut sections)?;
    Ok(render(&sections))
}

/// Builds and runs the defaults example (with `--workspace`, so that the
/// dependencies keep the features of the workspace's build) and parses its JSON.
fn defaults(mut cargo: Command) -> anyhow::Result<Value> {
    cargo.args([
        "build",
        "--workspace",
        "--example",
        DEFAULTS_EXAMPLE,
        "--message-format=json-render-diagnostics",
    ]);
    cargo.stdout(Stdio::piped()).stderr(Stdio::inherit());
    let shown = format!("{cargo:?}");
    eprintln!("xtask: {shown}");
    let out = cargo.output().with_context(|| format!("running {shown}"))?;
    if !out.status.success() {
        bail!(
            "building the config defaults failed ({}): {shown}",
            out.status
        );
    }
    let executable = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .filter(|m| m["reason"] == "compiler-artifact" && m["target"]["name"] == DEFAULTS_EXAMPLE)
        .find_map(|m| m["executable"].as_str().map(PathBuf::from))
        .with_context(|| format!("{shown} named no executable of {DEFAULTS_EXAMPLE}"))?;
    let run = Command::new(&executable)
        .output()
        .with_context(|| format!("running {}", executable.display()))?;
    if !run.status.success() {
        bail!(
            "{} failed ({}): {}",
            executable.display(),
            run.status,
            String::from_utf8_lossy(&run.stderr)
        );
    }
    serde_json::from_slice(&run.stdout).context("the config defaults are not JSON")
}

/// What serde's attributes on a struct, enum or field say.
#[derive(Default)]
struct Serde {
    rename: Option<String>,
    rename_all: Option<String>,
    default: bool,
    skip: bool,
}

impl Serde {
    fn of(attrs: &[syn::Attribute]) -> syn::Result<Serde> {
        let mut s = Serde::default();
        for attr in attrs.iter().filter(|a| a.path().is_ident("serde")) {
            attr.parse_nested_meta(|meta| {
                let name = meta.path.get_ident().map(ToString::to_string);
                match name.as_deref() {
                    Some("rename") => {
                        s.rename = Some(meta.value()?.parse::<syn::LitStr>()?.value())
                    }
                    Some("rename_all") => {
                        s.rename_all = Some(meta.value()?.parse::<syn::LitStr>()?.value())
                    }
                    Some("default") => {
                        s.default = true;
                        if meta.input.peek(syn::Token![=]) {
                            meta.value()?.parse::<syn::LitStr>()?;
                        }
                    }
                    Some("skip" | "skip_deserializing") => s.skip = true,
                    _ => {
                        if meta.input.peek(syn::Token![=]) {
                            meta.value()?.parse::<syn::Expr>()?;
                        }
                    }
                }
                Ok(())
            })?;
        }
        Ok(s)
    }
}

/// A doc comment as one line of text (paragraphs joined by a space).
fn doc_text(attrs: &[syn::Attribute]) -> String {
    let mut words = Vec::new();
    for attr in attrs.iter().filter(|a| a.path().is_ident("doc")) {
        if let syn::Meta::NameValue(nv) = &attr.meta
            && let syn::Expr::Lit(syn::ExprLit {
                lit: syn::Lit::Str(s),
                ..
            }) = &nv.value
        {
            words.extend(s.value().split_whitespace().map(str::to_string));
        }
    }
    words.join(" ")
}

/// One struct of the config crate.
struct Struct {
    file: String,
    doc: String,
    serde: Serde,
    fields: Vec<syn::Field>,
}

/// The config crate's structs, enums and type aliases, by name.
struct Source {
    structs: HashMap<String, Struct>,
    enums: HashMap<String, (Serde, Vec<String>)>,
    aliases: HashMap<String, syn::Type>,
}

/// One section of the reference: a table (`[gate.detector]`) or an array of
/// tables (`[[camera]]`) and its keys.
struct Section {
    path: String,
    array: bool,
    doc: String,
    keys: Vec<Key>,
}

/// One key of a section.
struct Key {
    name: String,
    ty: String,
    default: String,
    doc: String,
}

impl Source {
    fn read(dir: &Path) -> anyhow::Result<Source> {
        let mut source = Source {
            structs: HashMap::new(),
            enums: HashMap::new(),
            aliases: HashMap::new(),
        };
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .with_context(|| format!("reading {}", dir.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "rs"))
            .filter(|p| p.file_name().is_some_and(|n| n != "tests.rs"))
            .collect();
        files.sort();
        for path in files {
            let file = format!(
                "shared/config/src/{}",
                path.file_name().unwrap_or_default().to_string_lossy()
            );
            let text = std::fs::read_to_string(&path).with_context(|| format!("reading {file}"))?;
            let parsed = syn::parse_file(&text).with_context(|| format!("parsing {file}"))?;
            for item in parsed.items {
                match item {
                    syn::Item::Struct(s) => {
                        let syn::Fields::Named(named) = s.fields else {
                            continue;
                        };
                        let serde =
                            Serde::of(&s.attrs).with_context(|| format!("{file}: {}", s.ident))?;
                        source.structs.insert(
                            s.ident.to_string(),
                            Struct {
                                file: file.clone(),
                                doc: doc_text(&s.attrs),
                                serde,
                                fields: named.named.into_iter().collect(),
                            },
                        );
                    }
                    syn::Item::Enum(e) => {
                        let derives_deserialize = e.attrs.iter().any(|a| {
                            a.path().is_ident("derive")
                                && a.parse_args_with(
                                    syn::punctuated::Punctuated::<syn::Path, syn::Token![,]>::parse_terminated,
                                )
                                .is_ok_and(|paths| {
                                    paths.iter().any(|p| {
                                        p.segments.last().is_some_and(|s| s.ident == "Deserialize")
                                    })
                                })
                        });
                        if derives_deserialize {
                            let serde = Serde::of(&e.attrs)
                                .with_context(|| format!("{file}: {}", e.ident))?;
                            let variants = e.variants.iter().map(|v| v.ident.to_string()).collect();
                            source.enums.insert(e.ident.to_string(), (serde, variants));
                        }
                    }
                    syn::Item::Type(t) => {
                        source.aliases.insert(t.ident.to_string(), *t.ty);
                    }
                    _ => {}
                }
            }
        }
        Ok(source)
    }

    /// Appends the section of struct `name` at `path` (and the sections below
    /// it) to `out`; `defaults` is its value in the defaults' JSON, if any.
    fn sections(
        &self,
        name: &str,
        path: &str,
        array: bool,
        field_doc: Option<&str>,
        defaults: Option<&Value>,
        out: &mut Vec<Section>,
    ) -> anyhow::Result<()> {
        let s = self
            .structs
            .get(name)
            .with_context(|| format!("no struct {name} in shared/config/src"))?;
        let mut doc = strip_section_prefix(&s.doc);
        if let Some(extra) = field_doc {
            doc = format!("{doc} {extra}").trim().to_string();
        }
        let index = out.len();
        out.push(Section {
            path: path.to_string(),
            array,
            doc,
            keys: Vec::new(),
        });
        for field in &s.fields {
            let serde = Serde::of(&field.attrs)
                .with_context(|| format!("{}: a serde attribute of {name}", s.file))?;
            if serde.skip {
                continue;
            }
            let ident = field
                .ident
                .as_ref()
                .map(ToString::to_string)
                .unwrap_or_default();
            let key = serde.rename.clone().unwrap_or(ident);
            let key_path = if path.is_empty() {
                key.clone()
            } else {
                format!("{path}.{key}")
            };
            let doc = doc_text(&field.attrs);
            if doc.is_empty() {
                bail!(
                    "{}: `{key_path}` ({name}) has no doc comment: every key is documented on its field",
                    s.file
                );
            }
            let value = defaults.and_then(|d| d.get(&key));
            let optional = generic(&field.ty, "Option");
            let inner = optional.unwrap_or(&field.ty);
            if let Some(sub) = self.struct_name(inner) {
                let extra = if path.is_empty() && optional.is_some() {
                    Some(doc.as_str())
                } else {
                    None
                };
                let value = value.filter(|v| !v.is_null());
                self.sections(&sub, &key_path, false, extra, value, out)?;
                continue;
            }
            if let Some(sub) = generic(inner, "Vec").and_then(|t| self.struct_name(t)) {
                let first = value.and_then(|v| v.get(0));
                let extra = path.is_empty().then_some(doc.as_str());
                self.sections(&sub, &key_path, true, extra, first, out)?;
                continue;
            }
            let required = !s.serde.default && !serde.default && optional.is_none();
            let ty = self
                .type_name(inner)
                .with_context(|| format!("{}: `{key_path}` ({name}.{key})", s.file))?;
            let (default, doc) = default_cell(
                &key_path,
                &s.file,
                &doc,
                required,
                optional.is_some(),
                value,
            )?;
            out[index].keys.push(Key {
                name: key,
                ty,
                default,
                doc,
            });
        }
        Ok(())
    }

    /// The name of the config struct `ty` is, if it is one.
    fn struct_name(&self, ty: &syn::Type) -> Option<String> {
        let name = last_ident(ty)?;
        self.structs.contains_key(&name).then_some(name)
    }

    /// How the reference names a key of type `ty`.
    fn type_name(&self, ty: &syn::Type) -> anyhow::Result<String> {
        if let syn::Type::Array(a) = ty {
            let n: usize = match &a.len {
                syn::Expr::Lit(syn::ExprLit {
                    lit: syn::Lit::Int(i),
                    ..
                }) => i.base10_parse()?,
                _ => bail!("an array whose length is not a literal"),
            };
            let elem = self.type_name(&a.elem)?;
            return Ok(format!("[{}]", vec![elem; n].join(", ")));
        }
        if let Some(t) = generic(ty, "Option") {
            return self.type_name(t);
        }
        if let Some(t) = generic(ty, "Vec") {
            return Ok(format!("array of {}", self.type_name(t)?));
        }
        let name = last_ident(ty).context("a type the reference cannot name")?;
        let scalar = match name.as_str() {
            "String" => Some("string"),
            "PathBuf" => Some("path"),
            "bool" => Some("boolean"),
            "f32" | "f64" => Some("number"),
            "u8" | "u16" | "u32" | "u64" | "usize" | "i32" | "i64" => Some("integer"),
            _ => None,
        };
        if let Some(s) = scalar {
            return Ok(s.to_string());
        }
        if let Some(alias) = self.aliases.get(&name) {
            return self.type_name(alias);
        }
        if let Some((serde, variants)) = self.enums.get(&name) {
            let names: Vec<String> = variants
                .iter()
                .map(|v| format!("`\"{}\"`", rename(v, serde.rename_all.as_deref())))
                .collect();
            return Ok(names.join(" or "));
        }
        if let Some((_, shown)) = CUSTOM_TYPES.iter().find(|(n, _)| *n == name) {
            return Ok(shown.to_string());
        }
        bail!(
            "type `{name}` is neither a derived enum, an alias nor in CUSTOM_TYPES of xtask/src/config_ref.rs"
        )
    }
}

/// `Some(T)` if `ty` is `wrapper<T>`.
fn generic<'a>(ty: &'a syn::Type, wrapper: &str) -> Option<&'a syn::Type> {
    let syn::Type::Path(p) = ty else {
        return None;
    };
    let last = p.path.segments.last()?;
    if last.ident != wrapper {
        return None;
    }
    let syn::PathArguments::AngleBracketed(args) = &last.arguments else {
        return None;
    };
    args.args.iter().find_map(|a| match a {
        syn::GenericArgument::Type(t) => Some(t),
        _ => None,
    })
}

/// The last path segment's name of `ty` (`PathBuf` of `std::path::PathBuf`).
fn last_ident(ty: &syn::Type) -> Option<String> {
    let syn::Type::Path(p) = ty else {
        return None;
    };
    p.path.segments.last().map(|s| s.ident.to_string())
}

/// A variant's name under serde's `rename_all`.
fn rename(variant: &str, rule: Option<&str>) -> String {
    let mut words = Vec::new();
    let mut word = String::new();
    for c in variant.chars() {
        if c.is_uppercase() && !word.is_empty() {
            words.push(std::mem::take(&mut word));
        }
        word.push(c);
    }
    words.push(word);
    let lower: Vec<String> = words.iter().map(|w| w.to_lowercase()).collect();
    match rule {
        Some("lowercase") => variant.to_lowercase(),
        Some("kebab-case") => lower.join("-"),
        Some("snake_case") => lower.join("_"),
        _ => variant.to_string(),
    }
}

/// A struct doc without its leading "`[section]`: ", capitalised.
fn strip_section_prefix(doc: &str) -> String {
    let rest = match doc.strip_prefix('`') {
        Some(rest) if rest.starts_with('[') => {
            rest.split_once("`: ").map_or(doc, |(_, after)| after)
        }
        _ => doc,
    };
    let mut chars = rest.chars();
    match chars.next() {
        Some(c) => c.to_uppercase().chain(chars).collect(),
        None => String::new(),
    }
}

/// The Default cell of a key and its description, after checking every
/// `Default <value>` its doc states against the real default (`value`).
fn default_cell(
    key: &str,
    file: &str,
    doc: &str,
    required: bool,
    optional: bool,
    value: Option<&Value>,
) -> anyhow::Result<(String, String)> {
    if required {
        return Ok(("required".into(), doc.to_string()));
    }
    let Some(value) = value else {
        if optional {
            return Ok(("unset".into(), doc.to_string()));
        }
        bail!("{file}: `{key}` has no value in the defaults of {DEFAULTS_EXAMPLE}");
    };
    if value.is_null() {
        // The code applies the prose's default (if any) when the key is unset.
        return Ok(("unset".into(), doc.to_string()));
    }
    let mut doc = doc.to_string();
    for stated in stated_defaults(&doc) {
        let same = match (&stated, value) {
            (Stated::Number(n, _), Value::Number(v)) => v.as_f64() == Some(*n),
            (Stated::Text(t, _), Value::String(v)) => t == v,
            (Stated::Bool(b, _), Value::Bool(v)) => b == v,
            _ => false,
        };
        if !same {
            bail!(
                "{file}: `{key}`: its doc says the default is {} but it is {value}: correct the doc comment or the default",
                stated.raw()
            );
        }
        // A bare "Default <value>." says no more than the Default column.
        doc = doc
            .replace(&format!(" Default {}.", stated.raw()), "")
            .replace(&format!("Default {}. ", stated.raw()), "");
        if doc == format!("Default {}.", stated.raw()) {
            doc.clear();
        }
    }
    if value.as_str() == Some("")
        && doc
            .split(". ")
            .any(|s| s.trim_end_matches('.') == "Required")
    {
        return Ok(("required".into(), doc));
    }
    let shown = match value {
        Value::String(s) => format!("`\"{s}\"`"),
        other => format!("`{other}`"),
    };
    Ok((shown, doc))
}

/// A default a doc comment states, and how it is written there.
enum Stated {
    Number(f64, String),
    Text(String, String),
    Bool(bool, String),
}

impl Stated {
    /// As written in the doc.
    fn raw(&self) -> &str {
        match self {
            Stated::Number(_, raw) | Stated::Text(_, raw) | Stated::Bool(_, raw) => raw,
        }
    }
}

/// Every literal default `doc` states: `Default 16`, `Default true`,
/// `` Default `false` ``, `` Default `"UTC"` ``. Defaults stated in other words
/// (`` Default: `cap` ``, `default: measured ...`) are not checked.
fn stated_defaults(doc: &str) -> Vec<Stated> {
    let mut found = Vec::new();
    for (i, _) in doc.match_indices("Default ") {
        let rest = &doc[i + "Default ".len()..];
        let (literal, raw) = match rest.strip_prefix('`') {
            Some(quoted) => match quoted.find('`') {
                Some(end) => (&quoted[..end], &rest[..end + 2]),
                None => continue,
            },
            None => {
                let end = rest
                    .find(|c: char| !(c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_')))
                    .unwrap_or(rest.len());
                let word = rest[..end].trim_end_matches('.');
                (word, word)
            }
        };
        let stated = if let Some(text) = literal.strip_prefix('"').and_then(|t| t.strip_suffix('"'))
        {
            Stated::Text(text.to_string(), raw.to_string())
        } else if literal == "true" || literal == "false" {
            Stated::Bool(literal == "true", raw.to_string())
        } else if let Ok(n) = literal.replace('_', "").parse::<f64>() {
            Stated::Number(n, raw.to_string())
        } else {
            continue;
        };
        found.push(stated);
    }
    found
}

/// The markdown of the reference.
fn render(sections: &[Section]) -> String {
    let mut md = Vec::new();
    let _ = write!(
        md,
        "<!-- Generated by `cargo xtask docs config` from the field docs in shared/config/src/\n     \
         and the defaults of isochron-config. Do not edit: change the doc comment, then run it. -->\n\
         # Configuration reference\n\n\
         For whoever writes a site's configuration file: every key of every section, its\n\
         type, its default and what it does. One TOML file describes a site;\n\
         [`config/demo.toml`](../config/demo.toml) (the demo on vtest.avi) and\n\
         [`config/site.example.toml`](../config/site.example.toml) are commented examples,\n\
         and [operating.md](operating.md#configuration) says how a site's file is checked and\n\
         changed. Relative paths in the file are relative to the file. Unknown keys are\n\
         errors, and every error names the file, the line, the key and what was expected:\n\n\
         ```\n\
         config/site.toml:9: key `camera[0].fps`: expected a number from 0.01 to 1000, found -1\n\
         ```\n\n\
         Polygons (camera `mask` and `zone` outlines, `costmap.segment` `polygon_m`) must be\n\
         simple: at least 3 finite points, no two edges crossing or touching. *required*: the\n\
         key has no default; *unset*: absent unless given (the description says what applies\n\
         then).\n\n\
         Sections: "
    );
    let index: Vec<String> = sections
        .iter()
        .filter(|s| !s.path.is_empty())
        .map(|s| format!("[`{}`](#{})", heading(s), anchor(&heading(s))))
        .collect();
    let _ = writeln!(md, "{}.", index.join(" · "));
    for s in sections.iter().filter(|s| !s.path.is_empty()) {
        let _ = write!(md, "\n## `{}`\n\n", heading(s));
        if !s.doc.is_empty() {
            let _ = write!(md, "{}\n\n", wrap(&s.doc, 88));
        }
        if s.keys.is_empty() {
            continue;
        }
        let _ = writeln!(md, "| key | type | default | description |");
        let _ = writeln!(md, "|---|---|---|---|");
        for k in &s.keys {
            let _ = writeln!(
                md,
                "| `{}` | {} | {} | {} |",
                k.name,
                cell(&k.ty),
                cell(&k.default),
                cell(&k.doc)
            );
        }
    }
    String::from_utf8_lossy(&md).into_owned()
}

/// `[path]` or `[[path]]`.
fn heading(s: &Section) -> String {
    if s.array {
        format!("[[{}]]", s.path)
    } else {
        format!("[{}]", s.path)
    }
}

/// GitHub's anchor of a heading `` `text` ``: lower case, spaces to `-`, other
/// punctuation but `-` and `_` dropped.
fn anchor(text: &str) -> String {
    text.chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c.to_ascii_lowercase()),
            _ => None,
        })
        .collect()
}

/// Text made safe for a table cell.
fn cell(text: &str) -> String {
    text.replace('|', "\\|")
}

/// `text` wrapped at `width` columns.
fn wrap(text: &str, width: usize) -> String {
    let mut lines = Vec::new();
    let mut line = String::new();
    for word in text.split_whitespace() {
        if !line.is_empty() && line.len() + 1 + word.len() > width {
            lines.push(std::mem::take(&mut line));
        }
        if !line.is_empty() {
            line.push(' ');
        }
        line.push_str(word);
    }
    lines.push(line);
    lines.join("\n")
}

#[cfg(test)]
mod tests;
