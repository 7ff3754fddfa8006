//! What the typed JSON reports share: the number that may not be computable, the pretty
//! printer, and the registry of reports with their JSON Schemas (`visco schema REPORT`,
//! committed as `host-sim/schemas/<report>.schema.json`).
//!
//! Every report is a `serde` struct with a top-level `schema_version`, written by
//! `serde_json`; its schema is derived from the same struct by `schemars`, so the published
//! schema cannot drift from the output. A report's `schema_version` goes up when a field is
//! removed, renamed or changes meaning or unit; adding a field keeps it.

use std::borrow::Cow;

use schemars::{json_schema, JsonSchema, Schema, SchemaGenerator};
use serde::de::{MapAccess, Visitor};
use serde::ser::SerializeMap;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// A computed number that may be non-finite (not computable: a fit without data, a ratio
/// over zero). JSON has no spelling for NaN or ±inf, so it is written `null` (as `serde_json`
/// does for any non-finite `f64`) and read back as NaN; its schema is "number or null".
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Num(pub f64);

impl From<f64> for Num {
    fn from(v: f64) -> Self {
        Num(v)
    }
}

impl Serialize for Num {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        // serde_json writes a non-finite f64 as null; say so here for any other serializer.
        if self.0.is_finite() {
            s.serialize_f64(self.0)
        } else {
            s.serialize_none()
        }
    }
}

impl<'de> Deserialize<'de> for Num {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        Ok(Num(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN)))
    }
}

impl JsonSchema for Num {
    fn schema_name() -> Cow<'static, str> {
        "Num".into()
    }
    fn inline_schema() -> bool {
        true
    }
    fn json_schema(_: &mut SchemaGenerator) -> Schema {
        json_schema!({
            "type": ["number", "null"],
            "description": "null when it could not be computed (non-finite)"
        })
    }
}

/// Maps `f64`s to [`Num`]s (for arrays of computed values).
pub fn nums(v: impl IntoIterator<Item = f64>) -> Vec<Num> {
    v.into_iter().map(Num).collect()
}

/// The report pretty-printed (two spaces per level) with a final newline, as written to disk.
pub fn to_pretty<T: Serialize>(report: &T) -> String {
    // Serialising these structs to a String cannot fail: every map key is a string and no
    // Serialize impl here returns an error.
    let mut s = serde_json::to_string_pretty(report).unwrap_or_default();
    s.push('\n');
    s
}

/// A JSON object whose keys are data (map names, parameter names), written in this order
/// (serde_json's own map would sort them); its schema: an object of `V`s.
#[derive(Debug, Clone, PartialEq)]
pub struct Ordered<V>(pub Vec<(String, V)>);

impl<V> Default for Ordered<V> {
    fn default() -> Self {
        Ordered(Vec::new())
    }
}

impl<V: Serialize> Serialize for Ordered<V> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(Some(self.0.len()))?;
        for (k, v) in &self.0 {
            m.serialize_entry(k, v)?;
        }
        m.end()
    }
}

impl<'de, V: Deserialize<'de>> Deserialize<'de> for Ordered<V> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visit<V>(std::marker::PhantomData<V>);
        impl<'de, V: Deserialize<'de>> Visitor<'de> for Visit<V> {
            type Value = Ordered<V>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("an object")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut a: A) -> Result<Ordered<V>, A::Error> {
                let mut v = Vec::new();
                while let Some(entry) = a.next_entry()? {
                    v.push(entry);
                }
                Ok(Ordered(v))
            }
        }
        d.deserialize_map(Visit(std::marker::PhantomData))
    }
}

impl<V: JsonSchema> JsonSchema for Ordered<V> {
    fn schema_name() -> Cow<'static, str> {
        format!("Ordered_{}", V::schema_name()).into()
    }
    fn inline_schema() -> bool {
        true
    }
    fn json_schema(g: &mut SchemaGenerator) -> Schema {
        let item = g.subschema_for::<V>();
        json_schema!({
            "type": "object",
            "additionalProperties": item
        })
    }
}

/// The value at a dotted path of keys and array indices in a parsed report, e.g.
/// `at(&report, "taps.0.k_n_per_m")`: for scripts and tests that read a report untyped.
pub fn at<'a>(v: &'a serde_json::Value, path: &str) -> Option<&'a serde_json::Value> {
    path.split('.')
        .try_fold(v, |v, part| match (v, part.parse::<usize>()) {
            (serde_json::Value::Array(a), Ok(i)) => a.get(i),
            _ => v.get(part),
        })
}

/// The reports the tools write: (name, what writes it).
pub const REPORTS: &[(&str, &str)] = &[
    ("identify", "visco identify RECORDING --json OUT.json"),
    ("diagnose", "visco diagnose RECORDING --json REPORT.json"),
    ("concealed", "visco concealed --json FILE.json"),
    ("demo", "visco demo --out DIR (DIR/report.json)"),
    ("sweep", "visco sweep --out DIR (DIR/sweep.json)"),
    ("faults", "visco faults --json FILE.json"),
];

/// The JSON Schema of the report `name` (one of [`REPORTS`]), pretty-printed with a final
/// newline: the text of `host-sim/schemas/<name>.schema.json`.
pub fn schema(name: &str) -> Option<String> {
    let s = match name {
        "identify" => schemars::schema_for!(crate::identify::IdentifyReport),
        "diagnose" => schemars::schema_for!(crate::diagnose::DiagnoseReport),
        "concealed" => schemars::schema_for!(crate::experiment::concealed::ConcealedReport),
        "demo" => schemars::schema_for!(crate::experiment::demo::DemoReport),
        "sweep" => schemars::schema_for!(crate::experiment::sweep::SweepReport),
        "faults" => schemars::schema_for!(crate::experiment::faults::FaultsReport),
        _ => return None,
    };
    Some(to_pretty(&s))
}
