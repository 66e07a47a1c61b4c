//! Text-format protobuf, as much of it as a TensorFlow text graph uses: nested
//! messages of `key: scalar` and `key { ... }` fields, read into [`Node`]s and
//! written back.

use super::TextGraphError;

/// One value of a text-format protobuf message: a scalar as written (strings keep
/// their quotes), or a nested message.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Value {
    Scalar(String),
    Message(Vec<(String, Value)>),
}

/// A node of the graph: name, op, inputs and its attributes (`attr` entries, kept
/// as written).
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Node {
    pub(super) name: String,
    pub(super) op: String,
    pub(super) input: Vec<String>,
    pub(super) attr: Vec<(String, Value)>,
}

/// Splits text-format protobuf into tokens: `{`, `}`, `:`, quoted strings (with
/// their quotes) and bare words; `#` starts a comment.
fn tokenize(text: &str) -> Result<Vec<String>, TextGraphError> {
    let mut tokens = Vec::new();
    let mut chars = text.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            c if c.is_whitespace() => {}
            '#' => {
                for c in chars.by_ref() {
                    if c == '\n' {
                        break;
                    }
                }
            }
            '{' | '}' | ':' => tokens.push(c.to_string()),
            '"' | '\'' => {
                let mut s = String::from(c);
                let mut closed = false;
                while let Some(d) = chars.next() {
                    s.push(d);
                    if d == '\\' {
                        if let Some(e) = chars.next() {
                            s.push(e);
                        }
                    } else if d == c {
                        closed = true;
                        break;
                    }
                }
                if !closed {
                    return Err(TextGraphError::Shape("an unterminated string".into()));
                }
                tokens.push(s);
            }
            _ => {
                let mut s = String::from(c);
                while let Some(&d) = chars.peek() {
                    if d.is_whitespace() || "{}:\"'#".contains(d) {
                        break;
                    }
                    s.push(d);
                    chars.next();
                }
                tokens.push(s);
            }
        }
    }
    Ok(tokens)
}

/// Parses the fields of one message from `tokens[*at..]` up to its closing `}`
/// (or the end, at the top level).
fn parse_fields(
    tokens: &[String],
    at: &mut usize,
    top: bool,
) -> Result<Vec<(String, Value)>, TextGraphError> {
    let bad = |what: &str| TextGraphError::Shape(format!("text graph: {what}"));
    let mut fields = Vec::new();
    loop {
        let Some(key) = tokens.get(*at) else {
            return if top {
                Ok(fields)
            } else {
                Err(bad("a message is not closed"))
            };
        };
        *at += 1;
        if key == "}" {
            return if top {
                Err(bad("an unmatched `}`"))
            } else {
                Ok(fields)
            };
        }
        if tokens.get(*at).is_some_and(|t| t == ":") {
            *at += 1;
        }
        let value = tokens
            .get(*at)
            .ok_or_else(|| bad("a field without value"))?;
        *at += 1;
        if value == "{" {
            let inner = parse_fields(tokens, at, false)?;
            fields.push((key.clone(), Value::Message(inner)));
        } else {
            fields.push((key.clone(), Value::Scalar(value.clone())));
        }
    }
}

/// A quoted string's contents.
fn unquote(s: &str) -> String {
    s.trim_matches(|c| c == '"' || c == '\'').to_string()
}

/// The nodes of a text graph.
pub(super) fn parse_graph(text: &str) -> Result<Vec<Node>, TextGraphError> {
    let tokens = tokenize(text)?;
    let mut at = 0;
    let fields = parse_fields(&tokens, &mut at, true)?;
    let mut nodes = Vec::new();
    for (key, value) in fields {
        let Value::Message(fields) = value else {
            continue;
        };
        if key != "node" {
            continue;
        }
        let mut node = Node {
            name: String::new(),
            op: String::new(),
            input: Vec::new(),
            attr: Vec::new(),
        };
        for (k, v) in fields {
            match (k.as_str(), v) {
                ("name", Value::Scalar(s)) => node.name = unquote(&s),
                ("op", Value::Scalar(s)) => node.op = unquote(&s),
                ("input", Value::Scalar(s)) => node.input.push(unquote(&s)),
                ("attr", Value::Message(entry)) => {
                    let key = entry.iter().find_map(|(k, v)| match (k.as_str(), v) {
                        ("key", Value::Scalar(s)) => Some(unquote(s)),
                        _ => None,
                    });
                    let value = entry.into_iter().find(|(k, _)| k == "value");
                    if let (Some(key), Some((_, value))) = (key, value) {
                        node.attr.push((key, value));
                    }
                }
                _ => {}
            }
        }
        nodes.push(node);
    }
    if nodes.is_empty() {
        return Err(TextGraphError::Shape("the graph has no nodes".into()));
    }
    Ok(nodes)
}

/// Writes `value` at `indent`.
fn write_value(out: &mut String, key: &str, value: &Value, indent: usize) {
    let pad = " ".repeat(indent);
    match value {
        Value::Scalar(s) => out.push_str(&format!("{pad}{key}: {s}\n")),
        Value::Message(fields) => {
            out.push_str(&format!("{pad}{key} {{\n"));
            for (k, v) in fields {
                write_value(out, k, v, indent + 2);
            }
            out.push_str(&format!("{pad}}}\n"));
        }
    }
}

/// The text graph of `nodes`.
pub(super) fn write_graph(nodes: &[Node]) -> String {
    let mut out = String::new();
    for n in nodes {
        out.push_str("node {\n");
        out.push_str(&format!("  name: \"{}\"\n", n.name));
        out.push_str(&format!("  op: \"{}\"\n", n.op));
        for i in &n.input {
            out.push_str(&format!("  input: \"{i}\"\n"));
        }
        for (k, v) in &n.attr {
            out.push_str("  attr {\n");
            out.push_str(&format!("    key: \"{k}\"\n"));
            write_value(&mut out, "value", v, 4);
            out.push_str("  }\n");
        }
        out.push_str("}\n");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_writes_text_format() {
        let text = r#"node {
  name: "a"
  op: "Const"
  attr { key: "value" value { tensor { dtype: DT_FLOAT tensor_shape { dim { size: 1 } } float_val: 2.5 } } }
}
# a comment
node { name: "b" op: "Relu6" input: "a" input: "x:1" attr { key: "s" value { s: "q\"uote" } } }
"#;
        let nodes = parse_graph(text).unwrap();
        assert_eq!(nodes.len(), 2);
        assert_eq!(nodes[1].input, vec!["a", "x:1"]);
        let again = parse_graph(&write_graph(&nodes)).unwrap();
        assert_eq!(nodes, again, "what is written parses back the same");
    }

    #[test]
    fn unterminated_text_is_an_error_not_a_panic() {
        assert!(parse_graph("node { name: \"a").is_err());
        assert!(parse_graph("node { name: \"a\" ").is_err());
        assert!(parse_graph("}").is_err());
        assert!(parse_graph("").is_err());
    }
}
