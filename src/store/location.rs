//! Where the store lives: the `store` setting, parsed, with a PostgreSQL password kept
//! out of every message.

use super::StoreError;

/// Where the store lives: the `store` setting.
#[derive(Clone, PartialEq, Eq)]
pub enum Location {
    /// `sqlite:PATH`: the embedded SQLite file `calibd.sqlite3` in folder PATH.
    Sqlite(std::path::PathBuf),
    /// `postgres://…`: a PostgreSQL database.
    Postgres(PgLocation),
}

/// A PostgreSQL location: the URL without a password, and the password from a file or an
/// environment variable (kept out of `Debug` and of every message).
#[derive(Clone, PartialEq, Eq)]
pub struct PgLocation {
    pub(super) url: String,
    pub(super) password: Option<String>,
}

impl std::fmt::Debug for Location {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Location::Sqlite(p) => write!(f, "sqlite:{}", p.display()),
            Location::Postgres(p) => p.fmt(f),
        }
    }
}

impl std::fmt::Debug for PgLocation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let pw = if self.password.is_some() {
            " (password set)"
        } else {
            ""
        };
        write!(f, "{}{pw}", self.url)
    }
}

impl Location {
    /// Parse a `store` setting: `sqlite:PATH` or a `postgres://` / `postgresql://` URL. A
    /// password inside the URL is refused (it would end up in config files and logs): give
    /// it as `password` (read from `password_file` or an environment variable).
    pub fn parse(s: &str, password: Option<String>) -> Result<Location, StoreError> {
        if let Some(path) = s.strip_prefix("sqlite:") {
            if path.is_empty() {
                return Err(StoreError::Location("`sqlite:` needs a folder".into()));
            }
            return Ok(Location::Sqlite(path.into()));
        }
        if !(s.starts_with("postgres://") || s.starts_with("postgresql://")) {
            return Err(StoreError::Location(
                "`store` must be `sqlite:FOLDER` or a `postgres://` URL".into(),
            ));
        }
        let cfg: postgres::Config = s
            .parse()
            .map_err(|_| StoreError::Location("the PostgreSQL URL does not parse".into()))?;
        if cfg.get_password().is_some() {
            return Err(StoreError::Location(
                "no password in the PostgreSQL URL: use `password_file` or CALIBD_STORE_PASSWORD"
                    .into(),
            ));
        }
        Ok(Location::Postgres(PgLocation {
            url: s.to_string(),
            password,
        }))
    }

    /// The location with its password never shown (for logs).
    pub fn display(&self) -> String {
        format!("{self:?}")
    }
}
