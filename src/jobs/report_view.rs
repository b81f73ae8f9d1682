//! A stored result as the report reads it: the kind's own result type, deserialised from
//! the stored JSON ([`Reportable`] over typed fields); kinds without a typed result, and a
//! stored result that no longer reads as its kind's type, are read by field name.

use serde::de::DeserializeOwned;
use serde_json::Value;

use crate::campaigns::results;
use crate::jobs::{humanoid, pcr, serial, tree};
use crate::report::JsonResult;
use crate::report::view::Reportable;

/// The report's view of a stored result document (envelope and kind's fields), by its
/// `kind`.
pub fn typed_result(result: &Value) -> Box<dyn Reportable + '_> {
    let kind = result.get("kind").and_then(Value::as_str).unwrap_or("");
    match kind {
        "serial.identify" => typed::<serial::identify::SerialCalibration>(kind, result),
        "serial.design" => typed::<serial::design::SerialDesign>(kind, result),
        "pcr.identify" => typed::<pcr::identify::PcrCalibration>(kind, result),
        "humanoid.identify" => typed::<humanoid::identify::HumanoidCalibration>(kind, result),
        "tree.identify" => typed::<tree::TreeCalibration>(kind, result),
        "cell.trical_campaign" => typed::<results::TricalCampaign>(kind, result),
        "cell.pcr_campaign" => typed::<results::PcrCampaign>(kind, result),
        "cell.mocap_campaign" => typed::<results::MocapCampaign>(kind, result),
        _ => Box::new(JsonResult(result)),
    }
}

/// `result` read as `T`, else by field name with a warning saying why.
fn typed<'a, T>(kind: &str, result: &'a Value) -> Box<dyn Reportable + 'a>
where
    T: DeserializeOwned + Reportable + 'static,
{
    match T::deserialize(result) {
        Ok(t) => Box::new(t),
        Err(e) => Box::new(Unread {
            json: JsonResult(result),
            why: format!(
                "the stored result does not read as a {kind} result ({e}); it is shown by field name"
            ),
        }),
    }
}

/// A result of a typed kind that did not read as its type (written by another calibd
/// version): shown by field name, with the reason among the warnings.
#[derive(Debug)]
struct Unread<'a> {
    json: JsonResult<'a>,
    why: String,
}

impl Reportable for Unread<'_> {
    fn embedded(&self) -> Option<&dyn Reportable> {
        Some(&self.json)
    }

    fn warnings(&self) -> Vec<String> {
        let mut w = self.json.warnings();
        w.push(self.why.clone());
        w
    }
}
