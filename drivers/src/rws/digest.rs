//! HTTP Digest authentication (RFC 2617, MD5, qop=auth) as used by RWS 1.0 on IRC5:
//! computing the `Authorization` header (driver) and checking it (mock).

use md5::{Digest, Md5};

/// Lower-case hex MD5 of `s`.
pub fn md5_hex(s: &str) -> String {
    crate::transcript::to_hex(&Md5::digest(s.as_bytes()))
}

/// Splits `key="value", key=value` parameter lists (quoted values may contain commas).
pub fn parse_params(s: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut rest = s.trim();
    while !rest.is_empty() {
        let Some(eq) = rest.find('=') else { break };
        let key = rest[..eq]
            .trim()
            .trim_start_matches(',')
            .trim()
            .to_ascii_lowercase();
        rest = rest[eq + 1..].trim_start();
        let value;
        if let Some(r) = rest.strip_prefix('"') {
            let end = r.find('"').unwrap_or(r.len());
            value = r[..end].to_string();
            rest = r.get(end + 1..).unwrap_or("");
        } else {
            let end = rest.find(',').unwrap_or(rest.len());
            value = rest[..end].trim().to_string();
            rest = &rest[end..];
        }
        rest = rest.trim_start().trim_start_matches(',').trim_start();
        out.push((key, value));
    }
    out
}

fn get<'a>(p: &'a [(String, String)], k: &str) -> Option<&'a str> {
    p.iter().find(|(a, _)| a == k).map(|(_, v)| v.as_str())
}

/// A server's Digest challenge.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Challenge {
    /// Realm, e.g. `validusers@robapi.abb`.
    pub realm: String,
    /// Server nonce.
    pub nonce: String,
    /// Opaque value to echo.
    pub opaque: Option<String>,
    /// True when the server offers `qop=auth`.
    pub qop_auth: bool,
}

impl Challenge {
    /// Parses a `WWW-Authenticate: Digest ...` header value.
    pub fn parse(header: &str) -> Option<Challenge> {
        let rest = header.trim().strip_prefix("Digest")?.trim();
        let p = parse_params(rest);
        if let Some(a) = get(&p, "algorithm")
            && !a.eq_ignore_ascii_case("MD5")
        {
            return None;
        }
        Some(Challenge {
            realm: get(&p, "realm")?.to_string(),
            nonce: get(&p, "nonce")?.to_string(),
            opaque: get(&p, "opaque").map(str::to_string),
            qop_auth: get(&p, "qop").is_some_and(|q| q.split(',').any(|x| x.trim() == "auth")),
        })
    }

    /// The `Authorization` header value for one request (`nc` counts uses of this nonce).
    pub fn authorization(
        &self,
        user: &str,
        password: &str,
        method: &str,
        uri: &str,
        nc: u32,
        cnonce: &str,
    ) -> String {
        let ha1 = md5_hex(&format!("{user}:{}:{password}", self.realm));
        let ha2 = md5_hex(&format!("{method}:{uri}"));
        let nc = format!("{nc:08x}");
        let mut h = format!(
            "Digest username=\"{user}\", realm=\"{}\", nonce=\"{}\", uri=\"{uri}\", algorithm=MD5",
            self.realm, self.nonce
        );
        let response = if self.qop_auth {
            h.push_str(&format!(", qop=auth, nc={nc}, cnonce=\"{cnonce}\""));
            md5_hex(&format!("{ha1}:{}:{nc}:{cnonce}:auth:{ha2}", self.nonce))
        } else {
            md5_hex(&format!("{ha1}:{}:{ha2}", self.nonce))
        };
        h.push_str(&format!(", response=\"{response}\""));
        if let Some(o) = &self.opaque {
            h.push_str(&format!(", opaque=\"{o}\""));
        }
        h
    }
}

/// Server-side check of an `Authorization` header: returns the nonce used when valid.
pub fn verify(
    header: &str,
    method: &str,
    realm: &str,
    user: &str,
    password: &str,
) -> Option<String> {
    let p = parse_params(header.trim().strip_prefix("Digest")?);
    if get(&p, "username")? != user || get(&p, "realm")? != realm {
        return None;
    }
    let nonce = get(&p, "nonce")?;
    let uri = get(&p, "uri")?;
    let ha1 = md5_hex(&format!("{user}:{realm}:{password}"));
    let ha2 = md5_hex(&format!("{method}:{uri}"));
    let expected = match get(&p, "qop") {
        Some(q) => md5_hex(&format!(
            "{ha1}:{nonce}:{}:{}:{q}:{ha2}",
            get(&p, "nc")?,
            get(&p, "cnonce")?
        )),
        None => md5_hex(&format!("{ha1}:{nonce}:{ha2}")),
    };
    (get(&p, "response")? == expected).then(|| nonce.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rfc2617_example() {
        // RFC 2617 section 3.5: Mufasa / Circle Of Life.
        let c = Challenge {
            realm: "testrealm@host.com".into(),
            nonce: "dcd98b7102dd2f0e8b11d0f600bfb0c093".into(),
            opaque: Some("5ccc069c403ebaf9f0171e9517f40e41".into()),
            qop_auth: true,
        };
        let h = c.authorization(
            "Mufasa",
            "Circle Of Life",
            "GET",
            "/dir/index.html",
            1,
            "0a4f113b",
        );
        assert!(
            h.contains("response=\"6629fae49393a05397450978507c4ef1\""),
            "{h}"
        );
        assert!(verify(&h, "GET", "testrealm@host.com", "Mufasa", "Circle Of Life").is_some());
        assert!(verify(&h, "POST", "testrealm@host.com", "Mufasa", "Circle Of Life").is_none());
        assert!(verify(&h, "GET", "testrealm@host.com", "Mufasa", "wrong").is_none());
    }

    #[test]
    fn parses_the_real_irc5_challenge() {
        let h = r#"Digest realm="validusers@robapi.abb", domain="/", qop="auth", nonce="abc,def", opaque="799d5", algorithm="MD5", stale="FALSE""#;
        let c = Challenge::parse(h).unwrap();
        assert_eq!(c.realm, "validusers@robapi.abb");
        assert_eq!(c.nonce, "abc,def");
        assert_eq!(c.opaque.as_deref(), Some("799d5"));
        assert!(c.qop_auth);
        assert!(Challenge::parse("Basic realm=\"x\"").is_none());
    }
}
