//! Bearer-token authentication and roles. Tokens are stored only as SHA-256 hashes (they
//! are 256-bit random strings, so a fast hash suffices) and compared in constant time;
//! a token never reaches a log line. Roles: `viewer` reads, `submitter` also submits,
//! cancels and uploads, `operator` also drives devices and manages schedules.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use axum::extract::FromRequestParts;
use axum::http::request::Parts;
use serde::{Deserialize, Serialize};

use super::{ApiError, AppState};
use crate::config::TokenConfig;
use crate::run::input::sha256_hex;

/// What a token may do; each role includes the ones before it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Read jobs, results, datasets, schedules.
    Viewer,
    /// Also submit, re-run and cancel jobs and upload datasets.
    Submitter,
    /// Also submit jobs that drive devices and manage schedules.
    Operator,
}

impl Role {
    /// Parse a role name.
    pub fn parse(s: &str) -> Option<Role> {
        match s {
            "viewer" => Some(Role::Viewer),
            "submitter" => Some(Role::Submitter),
            "operator" => Some(Role::Operator),
            _ => None,
        }
    }

    /// The role's name.
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Viewer => "viewer",
            Role::Submitter => "submitter",
            Role::Operator => "operator",
        }
    }
}

/// Why the token setup failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AuthError {
    /// The token file could not be read or written.
    #[error("auth: {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A configured hash is not 64 hex digits.
    #[error("auth: token `{0}`: sha256 must be 64 hex digits")]
    BadHash(String),
    /// No random bytes.
    #[error("auth: no random source: {0}")]
    Random(String),
}

/// The known tokens.
#[derive(Debug, Clone, Default)]
pub struct Auth {
    /// Name (shared by every request that shows the token) and role, by token hash.
    by_hash: HashMap<[u8; 32], (Arc<str>, Role)>,
    /// Reads allowed without a token.
    pub anonymous_read: bool,
}

fn decode_hex(s: &str) -> Option<[u8; 32]> {
    let s = s.trim();
    if s.len() != 64 {
        return None;
    }
    let mut out = [0u8; 32];
    for (i, o) in out.iter_mut().enumerate() {
        *o = u8::from_str_radix(s.get(2 * i..2 * i + 2)?, 16).ok()?;
    }
    Some(out)
}

fn digest(token: &str) -> [u8; 32] {
    use sha2::Digest;
    sha2::Sha256::digest(token.as_bytes()).into()
}

/// A new random token (64 hex digits).
pub fn new_token() -> Result<String, AuthError> {
    let mut b = [0u8; 32];
    getrandom::fill(&mut b).map_err(|e| AuthError::Random(e.to_string()))?;
    Ok(b.iter().map(|x| format!("{x:02x}")).collect())
}

/// The hex SHA-256 a config stores for `token`.
pub fn hash_token(token: &str) -> String {
    sha256_hex(token.as_bytes())
}

/// Read `dir/operator.token`, creating it (mode 0600) with a new token if absent.
pub fn operator_token_file(dir: &Path) -> Result<(PathBuf, String), AuthError> {
    let path = dir.join("operator.token");
    let io = |source| AuthError::Io {
        path: path.clone(),
        source,
    };
    match std::fs::read_to_string(&path) {
        Ok(t) if !t.trim().is_empty() => return Ok((path, t.trim().to_string())),
        Ok(_) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(io(e)),
    }
    std::fs::create_dir_all(dir).map_err(io)?;
    let token = new_token()?;
    let mut opts = std::fs::OpenOptions::new();
    opts.write(true).create(true).truncate(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        opts.mode(0o600);
    }
    use std::io::Write;
    let mut f = opts.open(&path).map_err(io)?;
    f.write_all(format!("{token}\n").as_bytes()).map_err(io)?;
    f.sync_all().map_err(io)?;
    Ok((path, token))
}

impl Auth {
    /// Tokens from the configuration.
    pub fn new(tokens: &[TokenConfig], anonymous_read: bool) -> Result<Auth, AuthError> {
        let mut by_hash = HashMap::new();
        for t in tokens {
            let h = decode_hex(&t.sha256).ok_or_else(|| AuthError::BadHash(t.name.clone()))?;
            by_hash.insert(h, (Arc::from(t.name.as_str()), t.role));
        }
        Ok(Auth {
            by_hash,
            anonymous_read,
        })
    }

    /// Add a token given in clear (the generated operator token).
    pub fn add_token(&mut self, name: &str, role: Role, token: &str) {
        self.by_hash.insert(digest(token), (name.into(), role));
    }

    /// Number of tokens.
    pub fn len(&self) -> usize {
        self.by_hash.len()
    }

    /// True if no token is configured.
    pub fn is_empty(&self) -> bool {
        self.by_hash.is_empty()
    }

    /// The name and role of `token`, if it is known.
    pub fn check(&self, token: &str) -> Option<(Arc<str>, Role)> {
        let d = digest(token);
        // Constant-time comparison against every stored hash (a HashMap lookup alone
        // would branch on the hash bytes; the hashes are few).
        let mut found = None;
        for (h, who) in &self.by_hash {
            let diff = h
                .iter()
                .zip(d.iter())
                .fold(0u8, |acc, (a, b)| acc | (a ^ b));
            if diff == 0 {
                found = Some(who.clone());
            }
        }
        found
    }
}

/// The caller of a request: who, and with which role (None: no token).
#[derive(Debug, Clone)]
pub struct Caller {
    /// Token name.
    pub name: Option<Arc<str>>,
    /// Role, if a valid token was given.
    pub role: Option<Role>,
    anonymous_read: bool,
}

impl Caller {
    /// Require at least `role`: 401 without a valid token, 403 with too small a role.
    pub fn require(&self, role: Role) -> Result<Role, ApiError> {
        match self.role {
            None => Err(ApiError::Unauthorized),
            Some(r) if r >= role => Ok(r),
            Some(r) => Err(ApiError::Forbidden(format!(
                "this needs the {} role; the token has {}",
                role.as_str(),
                r.as_str()
            ))),
        }
    }

    /// Require read access (a token, unless anonymous reads are allowed).
    pub fn require_read(&self) -> Result<(), ApiError> {
        if self.anonymous_read || self.role.is_some() {
            Ok(())
        } else {
            Err(ApiError::Unauthorized)
        }
    }
}

/// The token of an `Authorization: Bearer TOKEN` value; the scheme is case-insensitive
/// (RFC 7235 section 2.1).
pub(crate) fn bearer_token(value: &str) -> Option<&str> {
    let (scheme, token) = value.trim().split_once(' ')?;
    let token = token.trim();
    (scheme.eq_ignore_ascii_case("bearer") && !token.is_empty()).then_some(token)
}

impl FromRequestParts<AppState> for Caller {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &AppState) -> Result<Self, ApiError> {
        let auth = &state.auth;
        let Some(h) = parts.headers.get(axum::http::header::AUTHORIZATION) else {
            return Ok(Caller {
                name: None,
                role: None,
                anonymous_read: auth.anonymous_read,
            });
        };
        let token = h
            .to_str()
            .ok()
            .and_then(bearer_token)
            .ok_or(ApiError::Unauthorized)?;
        // A token that is given but wrong is refused even for reads.
        let (name, role) = auth.check(token).ok_or(ApiError::Unauthorized)?;
        Ok(Caller {
            name: Some(name),
            role: Some(role),
            anonymous_read: auth.anonymous_read,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_are_checked_by_hash_and_roles_are_ordered() {
        let t = TokenConfig {
            name: "v".into(),
            role: Role::Viewer,
            sha256: hash_token("secret-viewer"),
        };
        let mut a = Auth::new(&[t], false).unwrap();
        a.add_token("op", Role::Operator, "secret-op");
        assert_eq!(a.check("secret-viewer"), Some(("v".into(), Role::Viewer)));
        assert_eq!(a.check("secret-op").map(|x| x.1), Some(Role::Operator));
        assert_eq!(a.check("secret"), None);
        assert!(Role::Operator > Role::Submitter && Role::Submitter > Role::Viewer);
        // SHA-256("abc") from FIPS 180-2.
        assert_eq!(
            hash_token("abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        let bad = TokenConfig {
            name: "x".into(),
            role: Role::Viewer,
            sha256: "12".into(),
        };
        assert!(matches!(
            Auth::new(&[bad], true),
            Err(AuthError::BadHash(_))
        ));
    }

    #[test]
    fn the_bearer_scheme_is_case_insensitive() {
        for v in ["Bearer abc", "bearer abc", "BEARER  abc ", " bEaReR abc"] {
            assert_eq!(bearer_token(v), Some("abc"), "{v:?}");
        }
        for v in ["Basic abc", "Bearer", "Bearer ", "Bearerabc", "abc"] {
            assert_eq!(bearer_token(v), None, "{v:?}");
        }
    }

    #[test]
    fn operator_token_file_is_private_and_stable() {
        let dir = tempfile::tempdir().unwrap();
        let (p, t1) = operator_token_file(dir.path()).unwrap();
        let (_, t2) = operator_token_file(dir.path()).unwrap();
        assert_eq!(t1, t2);
        assert_eq!(t1.len(), 64);
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&p).unwrap().permissions().mode();
            assert_eq!(mode & 0o777, 0o600);
        }
    }
}
