//! 3D parameters XML (`GetParameters 3D`): marker labels parsed with a real XML parser
//! (quick-xml), unknown elements ignored; and the writer used by the mock.

use quick_xml::Reader;
use quick_xml::events::Event;

use crate::error::CodecError;

/// What calibd needs from the 3D settings.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Settings3d {
    /// `AxisUpwards`, e.g. `+Z`.
    pub axis_upwards: String,
    /// Marker labels in data order.
    pub labels: Vec<String>,
}

/// Parses a `QTM_Parameters_Ver_1.xx` document with a `The_3D` section.
pub fn parse_3d(xml: &str) -> Result<Settings3d, CodecError> {
    let mut r = Reader::from_str(xml);
    let mut path: Vec<String> = Vec::new();
    let mut out = Settings3d::default();
    let mut seen_3d = false;
    let mut declared: Option<usize> = None;
    let mut text = String::new();
    let bad = |e: &dyn std::fmt::Display| CodecError::malformed(format!("3D parameters XML: {e}"));
    loop {
        match r.read_event().map_err(|e| bad(&e))? {
            Event::Start(s) => {
                let name = String::from_utf8_lossy(s.name().as_ref()).into_owned();
                seen_3d |= name == "The_3D";
                path.push(name);
                text.clear();
            }
            Event::Text(t) => text.push_str(&t.xml_content().map_err(|e| bad(&e))?),
            Event::CData(t) => text.push_str(&t.decode().map_err(|e| bad(&e))?),
            Event::GeneralRef(g) => match g.resolve_char_ref().map_err(|e| bad(&e))? {
                Some(c) => text.push(c),
                None => {
                    let name = g.decode().map_err(|e| bad(&e))?;
                    let v = quick_xml::escape::resolve_predefined_entity(&name)
                        .ok_or_else(|| bad(&format!("unknown entity &{name};")))?;
                    text.push_str(v);
                }
            },
            Event::End(_) => {
                let v = text.trim().to_string();
                let tail: Vec<&str> = path.iter().rev().take(3).map(String::as_str).collect();
                match tail.as_slice() {
                    ["Name", "Label", "The_3D", ..] => out.labels.push(v),
                    ["AxisUpwards", "The_3D", ..] => out.axis_upwards = v,
                    ["Labels", "The_3D", ..] => {
                        declared = Some(
                            v.parse()
                                .map_err(|_| bad(&format!("Labels {v:?} is not a count")))?,
                        )
                    }
                    _ => {}
                }
                path.pop();
                text.clear();
            }
            Event::Eof => break,
            _ => {}
        }
    }
    if !seen_3d {
        return Err(CodecError::malformed(
            "3D parameters XML has no The_3D element",
        ));
    }
    if let Some(n) = declared {
        if n != out.labels.len() {
            return Err(CodecError::malformed(format!(
                "3D parameters: Labels says {n} but {} Label elements follow",
                out.labels.len()
            )));
        }
    }
    Ok(out)
}

fn escape(s: &str) -> String {
    quick_xml::escape::escape(s).into_owned()
}

/// Writes the 3D parameters document the mock serves.
pub fn write_3d(version: &str, s: &Settings3d) -> String {
    let mut x = format!(
        "<QTM_Parameters_Ver_{version}><The_3D><AxisUpwards>{}</AxisUpwards>\
         <CalibrationTime>2026.11.22 08:00:00</CalibrationTime><Labels>{}</Labels>",
        escape(&s.axis_upwards),
        s.labels.len()
    );
    for l in &s.labels {
        x.push_str(&format!(
            "<Label><Name>{}</Name><RGBColor>ff00ff</RGBColor><Trajectory_Type>Labeled</Trajectory_Type></Label>",
            escape(l)
        ));
    }
    x.push_str(&format!(
        "<Bones></Bones></The_3D></QTM_Parameters_Ver_{version}>"
    ));
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spec_template_parses() {
        let xml = r#"<QTM_Parameters_Ver_1.25><The_3D><AxisUpwards>+Z</AxisUpwards>
<CalibrationTime>2011.09.23 11:23:11</CalibrationTime><Labels>2</Labels>
<Label><Name>th12</Name><RGBColor>ff00ff</RGBColor></Label>
<Label><Name>r_asis</Name><RGBColor>00ffff</RGBColor></Label>
<Bones><Bone From="fromName" To="toName" Color="ffff00"/></Bones></The_3D></QTM_Parameters_Ver_1.25>"#;
        let s = parse_3d(xml).unwrap();
        assert_eq!(s.labels, vec!["th12", "r_asis"]);
        assert_eq!(s.axis_upwards, "+Z");
    }

    #[test]
    fn round_trip_with_escaping_and_errors() {
        let s = Settings3d {
            axis_upwards: "+Y".into(),
            labels: vec!["a&b".into(), "<c>".into()],
        };
        assert_eq!(parse_3d(&write_3d("1.25", &s)).unwrap(), s);
        assert!(parse_3d("<a><b></a>").is_err());
        assert!(parse_3d("<QTM_Parameters_Ver_1.25/>").is_err());
        let wrong = "<P><The_3D><Labels>3</Labels><Label><Name>x</Name></Label></The_3D></P>";
        assert!(
            parse_3d(wrong)
                .unwrap_err()
                .to_string()
                .contains("Labels says 3")
        );
    }
}
