//! Credentials kept out of what isochron prints: a camera source's password — in
//! a URL's user info, a query parameter or a GStreamer element's property —
//! shown as `***` in logs, status, `doctor` and errors.

use std::borrow::Cow;

/// The mask a secret is shown as.
pub const MASK: &str = "***";

/// Names of `key=value` pairs whose values are secrets (matched without regard
/// to case): URL query parameters cameras take (`?user=admin&password=…`) and
/// `rtspsrc`'s `user-pw` property.
const SECRET_KEYS: [&str; 7] = [
    "password", "passwd", "pass", "pwd", "user-pw", "token", "secret",
];

/// `text` with every credential in it masked: the password of each URL's user
/// info (`rtsp://admin:***@host/`; a user alone is kept) and the value of each
/// `key=value` whose key names a secret (`?password=***`, `user-pw=***`).
/// Borrowed when there is nothing to mask.
pub fn redact(text: &str) -> Cow<'_, str> {
    let spans = secret_spans(text);
    if spans.is_empty() {
        return Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(text.len());
    let mut at = 0;
    for (start, end) in spans {
        if start < at {
            continue;
        }
        out.push_str(&text[at..start]);
        out.push_str(MASK);
        at = end;
    }
    out.push_str(&text[at..]);
    Cow::Owned(out)
}

/// Where a value ends: the delimiters of URLs, query strings, pipelines and
/// quoted text.
fn ends_value(c: char) -> bool {
    c.is_whitespace() || matches!(c, '&' | '#' | '"' | '\'' | '!' | ',' | ';')
}

/// The byte ranges of the secrets in `text`, in order.
fn secret_spans(text: &str) -> Vec<(usize, usize)> {
    let mut spans = Vec::new();
    // User info passwords: between the first ':' of the user info and its
    // last '@' (a password may hold '@'; the authority ends at '/', '?' or a
    // delimiter).
    let mut from = 0;
    while let Some(found) = text[from..].find("://") {
        let authority_start = from + found + 3;
        let authority_len = text[authority_start..]
            .find(|c: char| matches!(c, '/' | '?') || ends_value(c))
            .unwrap_or(text.len() - authority_start);
        let authority = &text[authority_start..authority_start + authority_len];
        if let Some(at) = authority.rfind('@')
            && let Some(colon) = authority[..at].find(':')
            && colon + 1 < at
        {
            spans.push((authority_start + colon + 1, authority_start + at));
        }
        from = authority_start + authority_len;
    }
    // key=value secrets.
    let lower = text.to_ascii_lowercase();
    for key in SECRET_KEYS {
        let pattern = format!("{key}=");
        let mut from = 0;
        while let Some(found) = lower[from..].find(&pattern) {
            let start = from + found;
            let value = start + pattern.len();
            let boundary = lower[..start]
                .chars()
                .next_back()
                .is_none_or(|c| !(c.is_ascii_alphanumeric() || c == '-' || c == '_'));
            let len = text[value..].find(ends_value).unwrap_or(text.len() - value);
            if boundary && len > 0 {
                spans.push((value, value + len));
            }
            from = value;
        }
    }
    spans.sort_unstable();
    spans
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_urls_password_is_masked_and_its_user_kept() {
        assert_eq!(
            redact("rtsp://admin:s3cret@10.0.0.5:554/stream1"),
            "rtsp://admin:***@10.0.0.5:554/stream1"
        );
        assert_eq!(
            redact("cannot open rtsps://u:p%40ss@cam.local/live?x=1 (refused)"),
            "cannot open rtsps://u:***@cam.local/live?x=1 (refused)"
        );
        // A password holding '@' (not percent-encoded, as people type it).
        assert_eq!(redact("rtsp://admin:p@ss@cam/"), "rtsp://admin:***@cam/");
    }

    #[test]
    fn text_without_credentials_is_borrowed_unchanged() {
        for text in [
            "rtsp://10.0.0.5:554/stream1",
            "rtsp://admin@cam/stream",
            "http://[::1]:8080/video",
            "video.avi",
            "passage=3",
        ] {
            assert!(
                matches!(redact(text), Cow::Borrowed(t) if t == text),
                "{text}"
            );
        }
    }

    #[test]
    fn secret_parameters_and_properties_are_masked() {
        assert_eq!(
            redact("http://cam/video.cgi?user=admin&password=hunter2&channel=1"),
            "http://cam/video.cgi?user=admin&password=***&channel=1"
        );
        assert_eq!(
            redact("rtspsrc location=rtsp://cam/s user-id=admin user-pw=hunter2 ! decodebin"),
            "rtspsrc location=rtsp://cam/s user-id=admin user-pw=*** ! decodebin"
        );
        assert_eq!(redact("?PWD=x&token=abc"), "?PWD=***&token=***");
    }

    #[test]
    fn every_url_in_a_line_is_masked() {
        assert_eq!(
            redact("rtsp://a:one@h1/x and rtsp://b:two@h2/y"),
            "rtsp://a:***@h1/x and rtsp://b:***@h2/y"
        );
    }
}
