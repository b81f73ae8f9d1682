//! Program modules: upload a module file with the file service (`PUT
//! /fileservice/$HOME/<file>`) and load it into T_ROB1 (`POST /rw/rapid/tasks/T_ROB1?
//! action=loadmod`, RAPID mastership held for the load and always released).

use super::{Actor, DEVICE, TASK};
use crate::error::DriverError;
use crate::link::Connect;
use crate::rws::http::url_encode;

/// A module file name the controller accepts: letters, digits, `_`, `-`, `.`, ending in
/// `.mod`, `.modx` or `.sys`.
fn check_file(file: &str) -> Result<(), DriverError> {
    let ok_chars = !file.is_empty()
        && file
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'));
    let lower = file.to_ascii_lowercase();
    let ext = [".mod", ".modx", ".sys"].iter().any(|e| lower.ends_with(e));
    if ok_chars && ext && !file.starts_with('.') {
        return Ok(());
    }
    Err(DriverError::InvalidRequest {
        device: DEVICE,
        detail: format!(
            "module file name {file:?} (letters, digits, `_`, `-`, `.`; .mod, .modx or .sys)"
        ),
    })
}

impl<C: Connect> Actor<C> {
    pub(super) async fn load_module(
        &mut self,
        file: &str,
        text: &str,
        stop: bool,
    ) -> Result<String, DriverError> {
        check_file(file)?;
        let path = format!("$HOME/{file}");
        self.exchange_body(
            "PUT",
            &format!("/fileservice/{path}"),
            Some((text.as_bytes(), "text/plain")),
        )
        .await?;
        if stop {
            self.exchange(
                "POST",
                "/rw/rapid/execution?action=stop",
                Some("stopmode=stop&usetsp=normal"),
            )
            .await?;
        }
        self.exchange("POST", "/rw/mastership?action=request", None)
            .await?;
        let form = format!("modulepath={}&replace=true", url_encode(&path));
        let loaded = self
            .exchange(
                "POST",
                &format!("/rw/rapid/tasks/{TASK}?action=loadmod"),
                Some(&form),
            )
            .await;
        let released = self
            .exchange("POST", "/rw/mastership?action=release", None)
            .await;
        loaded?;
        released?;
        Ok(path)
    }
}

#[cfg(test)]
mod tests {
    use super::check_file;

    #[test]
    fn module_file_names_are_checked() {
        assert!(check_file("PickPlace.mod").is_ok());
        assert!(check_file("a_b-2.modx").is_ok());
        for bad in ["", "../x.mod", "x.txt", "a b.mod", ".mod", "x/y.mod"] {
            assert!(check_file(bad).is_err(), "{bad}");
        }
    }
}
