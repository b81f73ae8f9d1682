//! Parameters XML (`GetParameters 3D`, `GetParameters General`): marker labels and the
//! capture frequency parsed with a real XML parser (quick-xml), unknown elements ignored;
//! and the writers used by the mock.

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
    if let Some(n) = declared
        && n != out.labels.len()
    {
        return Err(CodecError::malformed(format!(
            "3D parameters: Labels says {n} but {} Label elements follow",
            out.labels.len()
        )));
    }
    Ok(out)
}

/// What calibd needs from the General settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct SettingsGeneral {
    /// Capture frequency (`General/Frequency`), Hz.
    pub frequency_hz: u32,
}

/// Reads the text of every element at `path` (outermost first, the root excluded: e.g.
/// `["General", "Frequency"]`) of a `QTM_Parameters_Ver_1.xx` document, in order.
fn texts_at(xml: &str, want: &[&str], what: &str) -> Result<Vec<String>, CodecError> {
    let mut r = Reader::from_str(xml);
    let mut path: Vec<String> = Vec::new();
    let mut text = String::new();
    let mut out = Vec::new();
    let bad = |e: &dyn std::fmt::Display| CodecError::malformed(format!("{what} XML: {e}"));
    loop {
        match r.read_event().map_err(|e| bad(&e))? {
            Event::Start(s) => {
                path.push(String::from_utf8_lossy(s.name().as_ref()).into_owned());
                text.clear();
            }
            Event::Text(t) => text.push_str(&t.xml_content().map_err(|e| bad(&e))?),
            Event::CData(t) => text.push_str(&t.decode().map_err(|e| bad(&e))?),
            Event::End(_) => {
                if path.len() == want.len() + 1 && path[1..].iter().zip(want).all(|(a, b)| a == b) {
                    out.push(text.trim().to_string());
                }
                path.pop();
                text.clear();
            }
            Event::Eof => break,
            _ => {}
        }
    }
    Ok(out)
}

/// Parses a `QTM_Parameters_Ver_1.xx` document with a `General` section: the capture
/// frequency is `General/Frequency` (the `Frequency` elements nested deeper, e.g. in
/// `Camera`, are other things).
pub fn parse_general(xml: &str) -> Result<SettingsGeneral, CodecError> {
    let f = texts_at(xml, &["General", "Frequency"], "General parameters")?;
    let [v] = f.as_slice() else {
        return Err(CodecError::malformed(format!(
            "General parameters XML has {} General/Frequency elements, not 1",
            f.len()
        )));
    };
    let frequency_hz = v.parse().map_err(|_| {
        CodecError::malformed(format!("General/Frequency {v:?} is not a frequency in Hz"))
    })?;
    Ok(SettingsGeneral { frequency_hz })
}

/// The `General` element the mock serves (inside a parameters document).
pub fn general_section(g: &SettingsGeneral) -> String {
    format!(
        "<General><Frequency>{}</Frequency><Capture_Time>10.000</Capture_Time>\
         <Start_On_External_Trigger>False</Start_On_External_Trigger>\
         <External_Time_Base><Enabled>False</Enabled><Signal_Source>Control port</Signal_Source>\
         <Frequency_Multiplier>1</Frequency_Multiplier><Frequency_Divisor>1</Frequency_Divisor>\
         </External_Time_Base>\
         <Camera><ID>1</ID><Model>Miqus M3</Model><Mode>Marker</Mode>\
         <Video_Frequency>{}</Video_Frequency></Camera></General>",
        g.frequency_hz, g.frequency_hz
    )
}

/// Writes a parameters document with the `General` and/or `The_3D` sections (as
/// `GetParameters General 3D` answers).
pub fn write_parameters(
    version: &str,
    general: Option<&SettingsGeneral>,
    three_d: Option<&Settings3d>,
) -> String {
    let g = general.map(general_section).unwrap_or_default();
    let t = three_d.map(the_3d_section).unwrap_or_default();
    format!("<QTM_Parameters_Ver_{version}>{g}{t}</QTM_Parameters_Ver_{version}>")
}

fn escape(s: &str) -> String {
    quick_xml::escape::escape(s).into_owned()
}

/// Writes the 3D parameters document the mock serves.
pub fn write_3d(version: &str, s: &Settings3d) -> String {
    write_parameters(version, None, Some(s))
}

/// The `The_3D` element the mock serves.
pub fn the_3d_section(s: &Settings3d) -> String {
    let mut x = format!(
        "<The_3D><AxisUpwards>{}</AxisUpwards>\
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
    x.push_str("<Bones></Bones></The_3D>");
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
    fn general_frequency_is_the_direct_child_only() {
        // Shape of a QTM 2023 reply to `GetParameters General` (cameras shortened).
        let xml = "<QTM_Parameters_Ver_1.25>\n<General>\n<Frequency>100</Frequency>\n\
<Capture_Time>10.000</Capture_Time>\n<Start_On_External_Trigger>False</Start_On_External_Trigger>\n\
<External_Time_Base><Enabled>False</Enabled><Nominal_Frequency>None</Nominal_Frequency></External_Time_Base>\n\
<Camera><ID>1</ID><Model>Miqus M3</Model><Frequency>25</Frequency></Camera>\n\
</General>\n</QTM_Parameters_Ver_1.25>";
        assert_eq!(parse_general(xml).unwrap().frequency_hz, 100);
        let g = SettingsGeneral { frequency_hz: 250 };
        assert_eq!(
            parse_general(&write_parameters("1.25", Some(&g), None)).unwrap(),
            g
        );
        // Both sections in one document (GetParameters General 3D).
        let s = Settings3d {
            axis_upwards: "+Z".into(),
            labels: vec!["a".into()],
        };
        let both = write_parameters("1.25", Some(&g), Some(&s));
        assert_eq!(parse_general(&both).unwrap(), g);
        assert_eq!(parse_3d(&both).unwrap(), s);
        assert!(parse_general(&write_3d("1.25", &s)).is_err());
        let e = parse_general("<P><General><Frequency>fast</Frequency></General></P>");
        assert!(e.unwrap_err().to_string().contains("\"fast\""));
        assert!(parse_general("<P><General><Frequency>1</General></P>").is_err());
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
