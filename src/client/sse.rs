//! A small Server-Sent Events parser: bytes in, `(event, data)` pairs out.

/// One parsed event.
#[derive(Debug, Clone, PartialEq)]
pub struct SseMessage {
    /// The `event:` field (`message` if absent).
    pub event: String,
    /// The `data:` lines joined with newlines.
    pub data: String,
}

/// Incremental parser; feed it chunks as they arrive.
#[derive(Debug, Default)]
pub struct SseParser {
    buf: String,
}

impl SseParser {
    /// Add a chunk and return every event it completes.
    pub fn push(&mut self, chunk: &[u8]) -> Vec<SseMessage> {
        self.buf.push_str(&String::from_utf8_lossy(chunk));
        if self.buf.contains('\r') {
            self.buf = self.buf.replace("\r\n", "\n").replace('\r', "\n");
        }
        let mut out = Vec::new();
        while let Some(i) = self.buf.find("\n\n") {
            let block: String = self.buf.drain(..i + 2).collect();
            let mut event = String::from("message");
            let mut data: Vec<&str> = Vec::new();
            for line in block.lines() {
                if let Some(v) = line.strip_prefix("event:") {
                    event = v.trim_start().to_string();
                } else if let Some(v) = line.strip_prefix("data:") {
                    data.push(v.strip_prefix(' ').unwrap_or(v));
                }
            }
            if !data.is_empty() {
                out.push(SseMessage {
                    event,
                    data: data.join("\n"),
                });
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn events_split_across_chunks_and_comments_are_skipped() {
        let mut p = SseParser::default();
        assert!(p.push(b": keep-alive\n\nevent: sta").is_empty());
        let m = p.push(b"te\ndata: {\"id\":1}\n\ndata: a\ndata: b\n\n");
        assert_eq!(
            m,
            vec![
                SseMessage {
                    event: "state".into(),
                    data: "{\"id\":1}".into()
                },
                SseMessage {
                    event: "message".into(),
                    data: "a\nb".into()
                },
            ]
        );
    }
}
