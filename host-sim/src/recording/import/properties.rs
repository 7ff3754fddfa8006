//! Java `.properties` text, as JPK writes its headers.
//!
//! JPK instruments run on Java and store every header with `java.util.Properties`: ISO-8859-1
//! text, `key=value` (or `key: value`, or `key value`), `#`/`!` comments, backslash escapes
//! (`\:`, `\ `, `\uXXXX`, ...) and lines continued by a trailing backslash. Reading it exactly
//! matters: the time stamps contain escaped colons, and instrument names escaped non-ASCII.
//! Every value remembers its line, so a complaint can point at it.

use std::collections::HashMap;

/// A parsed properties file: key → (value, 1-based line of the key).
#[derive(Debug, Clone, Default)]
pub struct Properties {
    map: HashMap<String, (String, u64)>,
    order: Vec<String>,
}

impl Properties {
    /// Parses the bytes of a properties file (ISO-8859-1: every byte is one character, so
    /// parsing cannot fail; a later duplicate key wins, as in Java).
    pub fn parse(bytes: &[u8]) -> Properties {
        let text: String = bytes.iter().map(|&b| b as char).collect();
        let mut props = Properties::default();
        let mut lines = text.split('\n').enumerate().peekable();
        while let Some((i, raw)) = lines.next() {
            let line_no = i as u64 + 1;
            let first = raw
                .trim_end_matches('\r')
                .trim_start_matches([' ', '\t', '\x0c']);
            if first.is_empty() || first.starts_with('#') || first.starts_with('!') {
                continue;
            }
            // Join continuation lines: an odd number of trailing backslashes.
            let mut logical = String::from(first);
            while ends_with_odd_backslashes(&logical) {
                logical.pop();
                match lines.next() {
                    Some((_, next)) => logical.push_str(
                        next.trim_end_matches('\r')
                            .trim_start_matches([' ', '\t', '\x0c']),
                    ),
                    None => break,
                }
            }
            let (key, value) = split_key_value(&logical);
            let key = unescape(&key);
            let value = unescape(&value);
            if !props.map.contains_key(&key) {
                props.order.push(key.clone());
            }
            props.map.insert(key, (value, line_no));
        }
        props
    }

    /// The value of a key.
    pub fn get(&self, key: &str) -> Option<&str> {
        self.map.get(key).map(|(v, _)| v.as_str())
    }

    /// The value and line of a key.
    pub fn get_with_line(&self, key: &str) -> Option<(&str, u64)> {
        self.map.get(key).map(|(v, l)| (v.as_str(), *l))
    }

    /// Keys in first-appearance order.
    pub fn keys(&self) -> impl Iterator<Item = &str> {
        self.order.iter().map(String::as_str)
    }

    /// Number of keys.
    pub fn len(&self) -> usize {
        self.map.len()
    }

    /// True without keys.
    pub fn is_empty(&self) -> bool {
        self.map.is_empty()
    }

    /// Inserts a key (used to expand shared references).
    pub fn insert(&mut self, key: String, value: String, line: u64) {
        if !self.map.contains_key(&key) {
            self.order.push(key.clone());
        }
        self.map.insert(key, (value, line));
    }
}

fn ends_with_odd_backslashes(s: &str) -> bool {
    s.bytes().rev().take_while(|&b| b == b'\\').count() % 2 == 1
}

/// Splits at the first unescaped `=`, `:` or blank, as Java does.
fn split_key_value(line: &str) -> (String, String) {
    let chars: Vec<char> = line.chars().collect();
    let mut i = 0;
    let mut key_end = chars.len();
    while i < chars.len() {
        match chars[i] {
            '\\' => i += 2,
            '=' | ':' | ' ' | '\t' | '\x0c' => {
                key_end = i;
                break;
            }
            _ => i += 1,
        }
    }
    let key: String = chars[..key_end.min(chars.len())].iter().collect();
    let mut j = key_end;
    while j < chars.len() && matches!(chars[j], ' ' | '\t' | '\x0c') {
        j += 1;
    }
    if j < chars.len() && matches!(chars[j], '=' | ':') {
        j += 1;
        while j < chars.len() && matches!(chars[j], ' ' | '\t' | '\x0c') {
            j += 1;
        }
    }
    let value: String = chars[j.min(chars.len())..].iter().collect();
    (key, value)
}

/// Resolves backslash escapes; malformed `\u` sequences are kept literally.
fn unescape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut it = s.chars().peekable();
    while let Some(c) = it.next() {
        if c != '\\' {
            out.push(c);
            continue;
        }
        match it.next() {
            Some('t') => out.push('\t'),
            Some('n') => out.push('\n'),
            Some('r') => out.push('\r'),
            Some('f') => out.push('\x0c'),
            Some('u') => {
                let hex: String = it.clone().take(4).collect();
                match (hex.len() == 4)
                    .then(|| u32::from_str_radix(&hex, 16).ok())
                    .flatten()
                    .and_then(char::from_u32)
                {
                    Some(ch) => {
                        out.push(ch);
                        for _ in 0..4 {
                            it.next();
                        }
                    }
                    None => out.push_str("\\u"),
                }
            }
            Some(other) => out.push(other),
            None => {}
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn java_rules() {
        let p = Properties::parse(
            b"#comment\n! also\n  a=1\nb : two words \nc\\:d=e\\:f\nlong=x\\\n   y\n\
              t=2016-03-31 17\\:51\\:14.543 +0200\nmu=100\\u00B5m\nempty=\nbare\n\r\nw\\ x = 3\r\n",
        );
        assert_eq!(p.get("a"), Some("1"));
        assert_eq!(p.get("b"), Some("two words "));
        assert_eq!(p.get("c:d"), Some("e:f"));
        assert_eq!(p.get("long"), Some("xy"));
        assert_eq!(p.get("t"), Some("2016-03-31 17:51:14.543 +0200"));
        assert_eq!(p.get("mu"), Some("100µm"));
        assert_eq!(p.get("empty"), Some(""));
        assert_eq!(p.get("bare"), Some(""));
        assert_eq!(p.get("w x"), Some("3"));
        assert_eq!(p.get_with_line("a"), Some(("1", 3)));
    }

    #[test]
    fn garbage_does_not_panic() {
        for bytes in [
            &b"\\"[..],
            b"\\u",
            b"\\u12",
            b"=\\",
            b"a=\\\n",
            b"\xff\xfe=\x00",
            b"\\uD800=x",
        ] {
            let _ = Properties::parse(bytes);
        }
    }
}
