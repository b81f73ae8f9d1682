//! The RAPID lexer: identifiers, numbers, strings and punctuation with their byte spans and
//! lines; comments (`!` to the end of the line), white space and the `%%%` header of old
//! `.mod` files are skipped. A character RAPID does not use is an error naming its line.

use super::RapidError;

/// What a token is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tok {
    /// A name or keyword (case-insensitive in RAPID).
    Ident,
    /// A numeric literal (no sign).
    Num,
    /// A string literal with its quotes.
    Str,
    /// Punctuation or an operator: `:=`, `<>`, `<=`, `>=` or one character.
    Punct,
}

/// One token: kind, byte span in the module text, line (from 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Token {
    /// Kind.
    pub kind: Tok,
    /// First byte.
    pub start: usize,
    /// One past the last byte.
    pub end: usize,
    /// Line of the first byte (from 1).
    pub line: usize,
}

impl Token {
    /// The token's text.
    pub fn text<'a>(&self, src: &'a str) -> &'a str {
        &src[self.start..self.end]
    }

    /// Whether the token is the keyword or name `kw` (ASCII case-insensitive).
    pub fn is(&self, src: &str, kw: &str) -> bool {
        self.kind == Tok::Ident && self.text(src).eq_ignore_ascii_case(kw)
    }

    /// Whether the token is the punctuation `p`.
    pub fn is_punct(&self, src: &str, p: &str) -> bool {
        self.kind == Tok::Punct && self.text(src) == p
    }
}

/// The tokens of a module text.
pub fn tokens(src: &str) -> Result<Vec<Token>, RapidError> {
    let b = src.as_bytes();
    let mut out = Vec::new();
    let mut i = skip_header(src);
    let mut line = 1 + src[..i].matches('\n').count();
    while i < b.len() {
        let c = b[i];
        let start = i;
        let tok = |kind, end, out: &mut Vec<Token>| {
            out.push(Token {
                kind,
                start,
                end,
                line,
            })
        };
        match c {
            b'\n' => {
                line += 1;
                i += 1;
            }
            b' ' | b'\t' | b'\r' | 0x0c => i += 1,
            b'!' => {
                while i < b.len() && b[i] != b'\n' {
                    i += 1;
                }
            }
            b'"' => {
                i += 1;
                loop {
                    match b.get(i) {
                        None | Some(b'\n') => {
                            return Err(RapidError::new(line, "string not closed on its line"));
                        }
                        Some(b'"') if b.get(i + 1) == Some(&b'"') => i += 2,
                        Some(b'"') => {
                            i += 1;
                            break;
                        }
                        Some(_) => i += 1,
                    }
                }
                tok(Tok::Str, i, &mut out);
            }
            b'0'..=b'9' => {
                i = number_end(b, i);
                tok(Tok::Num, i, &mut out);
            }
            b'.' if b.get(i + 1).is_some_and(u8::is_ascii_digit) => {
                i = number_end(b, i);
                tok(Tok::Num, i, &mut out);
            }
            c if c.is_ascii_alphabetic() || c == b'_' => {
                while i < b.len() && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
                    i += 1;
                }
                tok(Tok::Ident, i, &mut out);
            }
            b':' | b'<' | b'>' => {
                let two = matches!(
                    (c, b.get(i + 1)),
                    (b':', Some(b'=')) | (b'<', Some(b'>' | b'=')) | (b'>', Some(b'='))
                );
                i += if two { 2 } else { 1 };
                tok(Tok::Punct, i, &mut out);
            }
            b'[' | b']' | b'(' | b')' | b'{' | b'}' | b',' | b';' | b'\\' | b'+' | b'-' | b'*'
            | b'/' | b'=' | b'.' | b'%' => {
                i += 1;
                tok(Tok::Punct, i, &mut out);
            }
            _ => {
                let ch = src[i..].chars().next().unwrap_or('?');
                return Err(RapidError::new(
                    line,
                    format!("unexpected character {ch:?}"),
                ));
            }
        }
    }
    Ok(out)
}

/// End of a numeric literal starting at `i`: digits, a fraction, an exponent.
fn number_end(b: &[u8], mut i: usize) -> usize {
    let digits = |mut i: usize| {
        while i < b.len() && b[i].is_ascii_digit() {
            i += 1;
        }
        i
    };
    i = digits(i);
    if b.get(i) == Some(&b'.') {
        i = digits(i + 1);
    }
    if matches!(b.get(i), Some(b'e' | b'E')) {
        let mut j = i + 1;
        if matches!(b.get(j), Some(b'+' | b'-')) {
            j += 1;
        }
        if b.get(j).is_some_and(u8::is_ascii_digit) {
            i = digits(j);
        }
    }
    i
}

/// Byte offset after the `%%%` ... `%%%` header of an old-style `.mod` file (0 without one).
fn skip_header(src: &str) -> usize {
    let t = src.trim_start();
    if !t.starts_with("%%%") {
        return 0;
    }
    let from = src.len() - t.len() + 3;
    match src[from..].find("%%%") {
        Some(k) => from + k + 3,
        None => 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_have_spans_and_lines_and_comments_are_skipped() {
        let src = "%%%\n VERSION:1\n%%%\nMODULE m ! c [\n  x:=-1.5E+3;s:=\"a\"\"b\";\nENDMODULE";
        let t = tokens(src).unwrap();
        let texts: Vec<&str> = t.iter().map(|t| t.text(src)).collect();
        assert_eq!(
            texts,
            [
                "MODULE",
                "m",
                "x",
                ":=",
                "-",
                "1.5E+3",
                ";",
                "s",
                ":=",
                "\"a\"\"b\"",
                ";",
                "ENDMODULE"
            ]
        );
        assert_eq!(t[0].line, 4);
        assert_eq!(t[2].line, 5);
        assert_eq!(t[11].line, 6);
        assert_eq!(t[5].kind, Tok::Num);
    }

    #[test]
    fn a_stray_character_or_open_string_names_its_line() {
        let e = tokens("MODULE m\n\n  x := 1 @ 2;\nENDMODULE").unwrap_err();
        assert_eq!(e.line, 3);
        assert!(e.message.contains("'@'"), "{e}");
        let e = tokens("MODULE m\n  s := \"abc;\nENDMODULE").unwrap_err();
        assert_eq!(e.line, 2);
    }
}
