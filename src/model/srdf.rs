//! The part of an SRDF (MoveIt semantic robot description) that posture design uses: the
//! link pairs whose collisions are disabled (adjacent links, pairs that never touch).

use super::ModelError;

/// Link pairs of every `<disable_collisions link1=".." link2=".."/>` element.
pub fn disabled_collisions(text: &str) -> Result<Vec<(String, String)>, ModelError> {
    let mut out = Vec::new();
    let mut rest = text;
    while let Some(i) = rest.find("<disable_collisions") {
        let tail = &rest[i..];
        let end = tail
            .find('>')
            .ok_or_else(|| ModelError::Parse("SRDF: unterminated <disable_collisions".into()))?;
        let elem = &tail[..end];
        let attr = |name: &str| -> Result<String, ModelError> {
            for q in ['"', '\''] {
                let key = format!("{name}={q}");
                if let Some(s) = elem.find(&key) {
                    let v = &elem[s + key.len()..];
                    if let Some(e) = v.find(q) {
                        return Ok(v[..e].to_string());
                    }
                }
            }
            Err(ModelError::Parse(format!(
                "SRDF: <disable_collisions> without `{name}`: {elem}>"
            )))
        };
        out.push((attr("link1")?, attr("link2")?));
        rest = &tail[end..];
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_the_talos_pairs() {
        let t = include_str!("../../tests/data/robots/talos/talos.srdf");
        let p = disabled_collisions(t).unwrap();
        assert_eq!(p.len(), 459);
        assert!(p.iter().any(|(a, b)| (a, b)
            == (
                &"arm_left_1_link".to_string(),
                &"arm_left_2_link".to_string()
            )
            || (b, a)
                == (
                    &"arm_left_1_link".to_string(),
                    &"arm_left_2_link".to_string()
                )));
        let e = disabled_collisions("<disable_collisions link1=\"a\" />")
            .unwrap_err()
            .to_string();
        assert!(e.contains("link2"), "{e}");
    }
}
