//! Reading back numbers that JSON cannot hold: serde_json writes a non-finite `f64` as
//! `null`, so a stored result reads `null` back as NaN (the report shows a dash).

use serde::{Deserialize, Deserializer};

/// A number, or NaN for `null` (a non-finite value as serialised).
pub fn f64_or_nan<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Deserialize)]
    struct X {
        #[serde(deserialize_with = "f64_or_nan")]
        v: f64,
    }

    #[test]
    fn null_reads_back_as_nan_and_numbers_as_themselves() {
        let inf = serde_json::json!({"v": f64::INFINITY});
        assert!(inf["v"].is_null(), "serde_json writes infinity as null");
        let x: X = serde_json::from_value(inf).expect("null reads");
        assert!(x.v.is_nan());
        let x: X = serde_json::from_value(serde_json::json!({"v": 2.5})).expect("a number");
        assert_eq!(x.v, 2.5);
    }
}
