//! The part of an SRDF (MoveIt semantic robot description) that posture design uses: the
//! link pairs whose collisions are disabled (adjacent links, pairs that never touch).

use quick_xml::Reader;
use quick_xml::events::{BytesStart, Event};

use super::ModelError;

/// Link pairs of every `<disable_collisions link1=".." link2=".."/>` element, read with an
/// XML parser (comments, CDATA and entities are XML's, not text to search).
pub fn disabled_collisions(text: &str) -> Result<Vec<(String, String)>, ModelError> {
    let mut r = Reader::from_str(text);
    let mut out = Vec::new();
    loop {
        let at = r.buffer_position();
        let ev = r
            .read_event()
            .map_err(|e| ModelError::Parse(format!("SRDF: {e} (near byte {at})")))?;
        match ev {
            Event::Start(e) | Event::Empty(e) if e.name().as_ref() == b"disable_collisions" => {
                out.push((attr(&e, "link1", at)?, attr(&e, "link2", at)?));
            }
            Event::Eof => break,
            _ => {}
        }
    }
    Ok(out)
}

/// The unescaped value of attribute `name`, or an error naming the element and the byte.
fn attr(e: &BytesStart<'_>, name: &str, at: u64) -> Result<String, ModelError> {
    let bad = |what: String| {
        ModelError::Parse(format!("SRDF: <disable_collisions> near byte {at}: {what}"))
    };
    let a = e
        .try_get_attribute(name)
        .map_err(|err| bad(format!("{err}")))?
        .ok_or_else(|| bad(format!("without `{name}`")))?;
    let v = a
        .unescape_value()
        .map_err(|err| bad(format!("`{name}`: {err}")))?;
    Ok(v.into_owned())
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
        // What string search got wrong: a commented-out pair is not a pair, entities are
        // decoded, and broken XML is an error, not a silent partial list.
        let p = disabled_collisions(
            "<robot><!-- <disable_collisions link1=\"x\" link2=\"y\"/> -->\
             <disable_collisions link1=\"a&amp;b\" link2='c' reason=\"Adjacent\"/></robot>",
        )
        .unwrap();
        assert_eq!(p, vec![("a&b".to_string(), "c".to_string())]);
        let e = disabled_collisions("<robot><disable_collisions link1=\"a\" link2=\"b\"></robot>")
            .unwrap_err()
            .to_string();
        assert!(e.contains("SRDF:") && e.contains("</robot>"), "{e}");
    }
}
