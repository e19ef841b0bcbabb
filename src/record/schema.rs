//! The one JSON Schema writer of every channel, recorded (`--record`) or served live
//! (`--foxglove`), so that a plot made on one works on the other, and both open in
//! Foxglove and Lichtblick with no configuration.
//!
//! Those viewers read a channel's JSON Schema with their own reader (`parseJsonSchema`
//! in `packages/mcap-support` of foxglove/studio and of lichtblick-suite/lichtblick),
//! which takes a small subset of JSON Schema and drops the whole channel — every plot
//! of it stays empty — on anything else ([`refusals`] says what it refuses). Foxglove
//! Studio's, the stricter, takes:
//! - an object only with `properties` (it iterates them; an object with none, a map,
//!   throws — Lichtblick now reads it as an empty object);
//! - per field one plain `type` of `boolean`, `string` (no `contentEncoding` but
//!   base64), `number`, `integer`, `object`, `array`; or a `oneOf` of numeric
//!   constants (an enumeration, as `foxglove.Log`'s `level`);
//! - array items of one such type (no nested arrays).
//!
//! adrive's types are generated (`schemars`) and use more: a nullable field is
//! `["number", "null"]` or an `anyOf` with `null`, a word from a list a `oneOf` of
//! string constants, a reading or a counter by name a map. [`readable`] writes each
//! schema into the subset: a nullable field is its type, a word from a list a
//! `string`, and a map an object whose properties are the keys this vehicle can have
//! (its devices' readings, its roles, every refusal's name, its DBC's signals) — known
//! before the first message, so a viewer is told them when it subscribes. A value
//! that is by turns a flag, a number and a word (the snapshot's `commanded`) has no
//! one type; it is left out of the schema (the per-device channels carry it as a
//! number), and so are the gate's typed blockers (`blocked_by`, each kind with fields of
//! its own; `blockers` has their words). The messages leave their null members out ([`without_nulls`]): each
//! still validates against its schema.

use crate::config::{ReadingKind, Role, VehicleConfig};
use schemars::JsonSchema;
use serde_json::{json, Map, Value};

/// The JSON Schema of `T` as generated, every subschema inlined (a viewer does not
/// follow `$ref`).
pub(crate) fn schema_of<T: JsonSchema>() -> Value {
    let generator = schemars::generate::SchemaSettings::draft07()
        .with(|s| s.inline_subschemas = true)
        .into_generator();
    generator.into_root_schema_for::<T>().to_value()
}

/// The keys of the snapshot's maps on one vehicle, by their path in the snapshot
/// (`devices.readings`: an array's items are passed through).
pub(crate) struct Keys {
    maps: Vec<(&'static str, Vec<(String, Value)>)>,
}

impl Keys {
    /// Every map of the snapshot of a run of `config`, with the keys it can have.
    pub(crate) fn of(config: &VehicleConfig) -> Keys {
        let count = || json!({ "type": "integer", "minimum": 0 });
        let word = || json!({ "type": "string" });
        let named = |names: &mut dyn Iterator<Item = String>, v: &dyn Fn() -> Value| {
            let mut out: Vec<(String, Value)> = Vec::new();
            for n in names {
                if !out.iter().any(|(k, _)| *k == n) {
                    out.push((n, v()));
                }
            }
            out
        };
        // A reading's type by its kind; a name two devices read as different kinds has
        // no one type and is left out.
        let mut readings: Vec<(String, Value)> = Vec::new();
        let mut mixed: Vec<String> = Vec::new();
        for r in config.devices.iter().flat_map(|d| &d.readings) {
            let t = reading_type(&r.kind);
            match readings.iter().find(|(n, _)| *n == r.name) {
                Some((_, s)) if s["type"] != t => mixed.push(r.name.clone()),
                Some(_) => {}
                None => readings.push((r.name.clone(), json!({ "type": t }))),
            }
        }
        readings.retain(|(n, _)| !mixed.contains(n));
        let units = named(
            &mut config
                .devices
                .iter()
                .flat_map(|d| &d.readings)
                .map(|r| r.name.clone()),
            &word,
        );
        let intake = || {
            crate::safety::Reject::ALL
                .iter()
                .map(|r| r.as_str().to_string())
        };
        let commands = config
            .devices
            .iter()
            .map(|d| d.name.clone())
            .chain(["accel".to_string()]);
        let signals = config.buses.iter().flat_map(|b| {
            b.dbc
                .messages()
                .iter()
                .flat_map(|m| m.signals().iter().map(|s| s.name().to_string()))
                .collect::<Vec<_>>()
        });
        Keys {
            maps: vec![
                (
                    "gate.roles",
                    named(&mut Role::ALL.iter().map(|r| r.as_str().to_string()), &word),
                ),
                ("devices.readings", readings),
                ("devices.reading_units", units),
                ("rejections", named(&mut intake(), &count)),
                ("net.commands", named(&mut commands.into_iter(), &count)),
                (
                    "net.rejected.datagram",
                    named(
                        &mut crate::net::proto::BadDatagram::ALL
                            .iter()
                            .map(|r| r.as_str().to_string()),
                        &count,
                    ),
                ),
                ("net.rejected.intake", named(&mut intake(), &count)),
                (
                    "net.rejected.refused",
                    named(
                        &mut crate::net::counters::NetRefusal::ALL
                            .iter()
                            .map(|r| r.as_str().to_string()),
                        &count,
                    ),
                ),
                (
                    "buses.frames.signals",
                    named(&mut signals.into_iter(), &word),
                ),
            ],
        }
    }

    fn get(&self, path: &str) -> Option<&[(String, Value)]> {
        self.maps
            .iter()
            .find(|(p, _)| *p == path)
            .map(|(_, k)| k.as_slice())
    }
}

/// The JSON type of a reading of `kind`, as its message carries it.
pub(crate) fn reading_type(kind: &ReadingKind) -> &'static str {
    match kind {
        ReadingKind::Number => "number",
        ReadingKind::Flag => "boolean",
        ReadingKind::States(_) => "string",
    }
}

/// `schema` written into what the viewers' reader takes (see the module's doc), the
/// snapshot's maps given `keys`. `None`: no schema the reader takes says it (the
/// field is left out of its object).
pub(crate) fn readable(schema: &Value, keys: &Keys) -> Value {
    field(schema, "", keys).unwrap_or_else(|| json!({ "type": "object", "properties": {} }))
}

fn join(path: &str, name: &str) -> String {
    if path.is_empty() {
        name.to_string()
    } else {
        format!("{path}.{name}")
    }
}

/// One schema at `path`, readable, or `None`.
fn field(s: &Value, path: &str, keys: &Keys) -> Option<Value> {
    let obj = s.as_object()?;
    let mut o = obj.clone();
    // A nullable type is its one other type.
    if let Some(Value::Array(types)) = o.get("type") {
        let t: Vec<&Value> = types.iter().filter(|t| *t != "null").collect();
        match t.as_slice() {
            [one] => {
                let one = (*one).clone();
                o.insert("type".into(), one);
            }
            _ => return None,
        }
    }
    for k in ["anyOf", "oneOf"] {
        let Some(Value::Array(alts)) = o.remove(k) else {
            continue;
        };
        let alts: Vec<&Value> = alts.iter().filter(|a| a["type"] != "null").collect();
        if k == "oneOf" && !alts.is_empty() && alts.iter().all(|a| a["const"].is_number()) {
            let alts = alts.into_iter().cloned().collect();
            o.insert(k.into(), Value::Array(alts));
        } else if !alts.is_empty()
            && alts
                .iter()
                .all(|a| a["const"].is_string() || a["enum"].is_array() && a["type"] == "string")
        {
            o.insert("type".into(), Value::from("string"));
        } else if let [one] = alts.as_slice() {
            let one = field(one, path, keys)?;
            for (key, v) in one.as_object()? {
                o.insert(key.clone(), v.clone());
            }
        } else {
            return None;
        }
    }
    if o.contains_key("oneOf") {
        o.remove("type");
        return Some(Value::Object(o));
    }
    match o.get("type").and_then(Value::as_str)? {
        "boolean" | "number" | "integer" => {}
        "string" => {
            if !(o.get("contentEncoding").is_none() || o["contentEncoding"] == "base64") {
                return None;
            }
        }
        "object" => {
            if o.get("properties").is_none() {
                // A map: its keys, if this vehicle's are known.
                let props: Map<String, Value> = keys.get(path)?.iter().cloned().collect();
                o.remove("additionalProperties");
                o.insert("properties".into(), Value::Object(props));
            } else {
                o.remove("additionalProperties");
            }
            let props = o["properties"].as_object()?.clone();
            let readable: Map<String, Value> = props
                .iter()
                .filter_map(|(n, v)| Some((n.clone(), field(v, &join(path, n), keys)?)))
                .collect();
            if let Some(Value::Array(req)) = o.get("required") {
                let req: Vec<Value> = req
                    .iter()
                    .filter(|r| r.as_str().is_some_and(|r| readable.contains_key(r)))
                    .cloned()
                    .collect();
                o.insert("required".into(), Value::Array(req));
            }
            o.insert("properties".into(), Value::Object(readable));
        }
        "array" => {
            let items = field(o.get("items")?, path, keys)?;
            if items["type"] == "array" || items.get("oneOf").is_some() {
                return None;
            }
            o.insert("items".into(), items);
        }
        _ => return None,
    }
    Some(Value::Object(o))
}

/// A message as it is recorded and served: every member whose value is null left out
/// (a viewer shows nothing for it either way, and a reader of the recording takes a
/// missing member for a null), so that it validates against its [`readable`] schema.
/// Members keep their order (a snapshot's readings and roles are in the vehicle
/// file's).
pub(crate) fn without_nulls(payload: &[u8]) -> Vec<u8> {
    match serde_json::from_slice::<Node>(payload) {
        Ok(n) => serde_json::to_vec(&n).unwrap_or_else(|_| payload.to_vec()),
        Err(_) => payload.to_vec(),
    }
}

/// A JSON value read in order, its null members dropped as it is read.
enum Node {
    Null,
    Plain(Value),
    Array(Vec<Node>),
    Object(Vec<(String, Node)>),
}

impl<'de> serde::Deserialize<'de> for Node {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Node, D::Error> {
        struct Visit;
        impl<'de> serde::de::Visitor<'de> for Visit {
            type Value = Node;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("JSON")
            }
            fn visit_unit<E>(self) -> Result<Node, E> {
                Ok(Node::Null)
            }
            fn visit_none<E>(self) -> Result<Node, E> {
                Ok(Node::Null)
            }
            fn visit_bool<E>(self, v: bool) -> Result<Node, E> {
                Ok(Node::Plain(v.into()))
            }
            fn visit_i64<E>(self, v: i64) -> Result<Node, E> {
                Ok(Node::Plain(v.into()))
            }
            fn visit_u64<E>(self, v: u64) -> Result<Node, E> {
                Ok(Node::Plain(v.into()))
            }
            fn visit_f64<E>(self, v: f64) -> Result<Node, E> {
                Ok(Node::Plain(v.into()))
            }
            fn visit_str<E>(self, v: &str) -> Result<Node, E> {
                Ok(Node::Plain(v.into()))
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut a: A) -> Result<Node, A::Error> {
                let mut out = Vec::new();
                while let Some(n) = a.next_element()? {
                    out.push(n);
                }
                Ok(Node::Array(out))
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, mut a: A) -> Result<Node, A::Error> {
                let mut out = Vec::new();
                while let Some((k, v)) = a.next_entry::<String, Node>()? {
                    if !matches!(v, Node::Null) {
                        out.push((k, v));
                    }
                }
                Ok(Node::Object(out))
            }
        }
        d.deserialize_any(Visit)
    }
}

impl serde::Serialize for Node {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::{SerializeMap, SerializeSeq};
        match self {
            Node::Null => s.serialize_unit(),
            Node::Plain(v) => v.serialize(s),
            Node::Array(items) => {
                let mut seq = s.serialize_seq(Some(items.len()))?;
                for i in items {
                    seq.serialize_element(i)?;
                }
                seq.end()
            }
            Node::Object(members) => {
                let mut m = s.serialize_map(Some(members.len()))?;
                for (k, v) in members {
                    m.serialize_entry(k, v)?;
                }
                m.end()
            }
        }
    }
}

/// Why Foxglove Studio's JSON Schema reader would refuse `schema`, field by field, as
/// it reads it; empty when it takes it. These are the rules of `parseJsonSchema`
/// (foxglove/studio, `packages/mcap-support/src/parseJsonSchema.ts`, the last open
/// source; Lichtblick's is the same but for a missing `properties`, which it takes as
/// none), written again so that a unit test needs no viewer: tests/foxglove_studio.rs
/// runs the real one, under Node.js, on a real recording and the live view.
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn refusals(schema: &Value) -> Vec<String> {
    fn object(s: &Value, path: &str, out: &mut Vec<String>) {
        if s["type"] != "object" {
            out.push(format!("{path}: expected type object, got {}", s["type"]));
            return;
        }
        let Some(props) = s["properties"].as_object() else {
            out.push(format!(
                "{path}: an object with no properties (Object.entries(undefined) throws)"
            ));
            return;
        };
        for (name, f) in props {
            let at = join(path, name);
            if let Some(alts) = f["oneOf"].as_array() {
                if !alts.iter().all(|a| a["const"].is_number()) {
                    out.push(format!("{at}: oneOf alternatives must have number values"));
                }
                continue;
            }
            match f["type"].as_str() {
                Some("boolean" | "number" | "integer") => {}
                Some("string") => {
                    if !(f["contentEncoding"].is_null() || f["contentEncoding"] == "base64") {
                        out.push(format!("{at}: unsupported contentEncoding"));
                    }
                }
                Some("object") => object(f, &at, out),
                Some("array") => match f["items"]["type"].as_str() {
                    Some("boolean" | "number" | "integer") => {}
                    Some("string") if f["items"]["contentEncoding"].is_null() => {}
                    Some("object") => object(&f["items"], &at, out),
                    _ => out.push(format!(
                        "{at}: unsupported array item type {}",
                        f["items"]["type"]
                    )),
                },
                _ => out.push(format!("{at}: unsupported type {}", f["type"])),
            }
        }
    }
    let mut out = Vec::new();
    object(schema, "", &mut out);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::message::Topic;

    fn shipped() -> Vec<(String, VehicleConfig)> {
        ["alice.toml", "cart.toml", "tractor.toml", "oscc.toml"]
            .into_iter()
            .map(|file| {
                let path = format!("{}/vehicles/{file}", env!("CARGO_MANIFEST_DIR"));
                (
                    file.to_string(),
                    crate::config::load(std::path::Path::new(&path)).unwrap(),
                )
            })
            .collect()
    }

    /// Foxglove Studio's reader takes the schema of every channel of every shipped
    /// vehicle, recorded and live alike (one writer), while it refuses the schemas as
    /// generated: a nullable field, a word from a list, a map.
    #[test]
    fn every_channel_s_schema_is_one_foxglove_studio_reads() {
        for (file, v) in shipped() {
            let mut raw_refused = 0;
            for t in Topic::channels(&v.devices, true)
                .into_iter()
                .chain([Topic::Record])
            {
                let (_, s) = t.schema(&v);
                let s: Value = serde_json::from_slice(&s).unwrap();
                let why = refusals(&s);
                assert!(why.is_empty(), "{file} {}: {why:?}", t.name(&v.devices));
                raw_refused += usize::from(!refusals(&t.generated(&v)).is_empty());
            }
            assert!(raw_refused > 3, "{file}: the check finds nothing to refuse");
        }
    }

    /// Every map of the snapshot is given its keys: none is left out but the values
    /// with no one type.
    #[test]
    fn the_snapshot_keeps_every_field_but_those_of_no_one_type() {
        let (_, oscc) = shipped().remove(3);
        let raw = Topic::Snapshot.generated(&oscc);
        let shown = readable(&raw, &Keys::of(&oscc));
        fn paths(s: &Value, at: &str, out: &mut Vec<String>) {
            let s = if s["type"] == "array" { &s["items"] } else { s };
            let s = s["anyOf"]
                .as_array()
                .and_then(|a| a.iter().find(|x| x["type"] != "null"))
                .unwrap_or(s);
            if let Some(p) = s["properties"].as_object() {
                for (n, f) in p {
                    let here = join(at, n);
                    out.push(here.clone());
                    paths(f, &here, out);
                }
            }
        }
        let (mut before, mut after) = (Vec::new(), Vec::new());
        paths(&raw, "", &mut before);
        paths(&shown, "", &mut after);
        let lost: Vec<&String> = before.iter().filter(|p| !after.contains(p)).collect();
        assert_eq!(
            lost,
            [
                "devices.commanded",
                "devices.executed",
                "gate.blocked_by",
                "gate.cause"
            ]
        );
        let readings = &shown["properties"]["devices"]["items"]["properties"]["readings"];
        assert_eq!(readings["properties"]["pressure"]["type"], "number");
        let signals = &shown["properties"]["buses"]["items"]["properties"]["frames"]["items"]
            ["properties"]["signals"]["properties"];
        assert!(signals.as_object().unwrap().len() > 5, "{signals}");
    }

    #[test]
    fn nulls_are_left_out_of_a_message() {
        let m = without_nulls(br#"{"z":2,"a":null,"b":{"c":null,"d":1.5},"e":[{"f":null},null]}"#);
        assert_eq!(
            String::from_utf8(m).unwrap(),
            r#"{"z":2,"b":{"d":1.5},"e":[{},null]}"#,
            "in order"
        );
    }
}
