//! The Foxglove WebSocket protocol, as much of it as a read-only live view speaks
//! (`foxglove/ws-protocol`, `docs/spec.md`): the subprotocol names, the server's JSON
//! messages (`serverInfo`, `advertise`, `status`), the binary message data frame and
//! the client's `subscribe` / `unsubscribe`. Pure functions over text and bytes.

use serde::Deserialize;
use serde_json::{json, Value};

/// The subprotocol names in use: current Foxglove asks for the first; Lichtblick
/// before its #819 and many bridges for the second. The wire format is the same.
pub(crate) const SUBPROTOCOLS: [&str; 2] = ["foxglove.sdk.v1", "foxglove.websocket.v1"];

/// Binary opcode of message data.
pub(crate) const MESSAGE_DATA: u8 = 1;

/// The subprotocol to answer with: the first one the client offers that this server
/// speaks. `offered`: the values of its `Sec-WebSocket-Protocol` headers.
pub(crate) fn choose<'a>(offered: impl IntoIterator<Item = &'a str>) -> Option<&'static str> {
    offered
        .into_iter()
        .flat_map(|v| v.split(','))
        .map(str::trim)
        .find_map(|p| SUBPROTOCOLS.iter().find(|s| **s == p).copied())
}

/// `serverInfo`: no capability at all — no client publishing, services, parameters,
/// time or assets: the live view only shows.
pub(crate) fn server_info(name: &str, session: &str, vehicle: &str) -> String {
    json!({
        "op": "serverInfo",
        "name": name,
        "capabilities": [],
        "metadata": { "vehicle": vehicle, "read_only": "true" },
        "sessionId": session,
    })
    .to_string()
}

/// One advertised channel.
pub struct Channel<'a> {
    pub id: u32,
    pub topic: &'a str,
    pub(crate) schema_name: &'a str,
    /// The JSON Schema, as text.
    pub schema: &'a str,
}

/// `advertise`: the channels, JSON messages with JSON Schemas.
pub fn advertise(channels: &[Channel]) -> String {
    let list: Vec<_> = channels
        .iter()
        .map(|c| {
            json!({
                "id": c.id,
                "topic": c.topic,
                "encoding": "json",
                "schemaName": c.schema_name,
                "schema": c.schema,
                "schemaEncoding": "jsonschema",
            })
        })
        .collect();
    json!({ "op": "advertise", "channels": list }).to_string()
}

/// `status`: 0 info, 1 warning, 2 error.
pub fn status(level: u8, message: &str) -> String {
    json!({ "op": "status", "level": level, "message": message }).to_string()
}

/// Message data: opcode 1, the subscription id (u32 LE), the log time (u64 ns LE), the
/// payload.
pub(crate) fn message_data(subscription: u32, log_time_ns: u64, payload: &[u8]) -> Vec<u8> {
    let mut b = Vec::with_capacity(13 + payload.len());
    b.push(MESSAGE_DATA);
    b.extend_from_slice(&subscription.to_le_bytes());
    b.extend_from_slice(&log_time_ns.to_le_bytes());
    b.extend_from_slice(payload);
    b
}

/// What a client asks.
#[derive(Debug, PartialEq)]
pub enum ClientOp {
    /// (subscription id, channel id) pairs.
    Subscribe(Vec<(u32, u32)>),
    Unsubscribe(Vec<u32>),
    /// Any other operation (publishing, services, parameters): not served here.
    Other(String),
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct Sub {
    id: u32,
    channel_id: u32,
}

#[derive(Deserialize)]
#[serde(tag = "op", rename_all = "camelCase")]
enum Op {
    Subscribe {
        subscriptions: Vec<Sub>,
    },
    #[serde(rename_all = "camelCase")]
    Unsubscribe {
        subscription_ids: Vec<u32>,
    },
}

/// A client's text message; an error names what was expected.
pub fn parse(text: &str) -> Result<ClientOp, String> {
    let v: serde_json::Value =
        serde_json::from_str(text).map_err(|e| format!("expected a JSON object: {e}"))?;
    let op = v["op"]
        .as_str()
        .ok_or("expected a JSON object with a string `op`")?
        .to_string();
    if op != "subscribe" && op != "unsubscribe" {
        return Ok(ClientOp::Other(op));
    }
    match serde_json::from_value::<Op>(v).map_err(|e| format!("{op}: {e}"))? {
        Op::Subscribe { subscriptions } => Ok(ClientOp::Subscribe(
            subscriptions.iter().map(|s| (s.id, s.channel_id)).collect(),
        )),
        Op::Unsubscribe { subscription_ids } => Ok(ClientOp::Unsubscribe(subscription_ids)),
    }
}

/// A schema as viewers read it. Foxglove's and Lichtblick's JSON Schema reader takes a
/// subset — one plain `type` per field, or a `oneOf` of numeric constants — and drops a
/// channel whose schema has anything else (`"Failed to parse channel schema"`), so
/// every plot of it stays empty. This rewrites the schemas adrive generates into that
/// subset: a nullable `["number", "null"]` is `"number"` (a union of scalars, the
/// widest: `string`, else `number`), a nullable `anyOf` is its one alternative, and an
/// enum of strings is a `string`. Nulls do not reach a viewer ([`without_nulls`]), so
/// every message still validates against what is advertised.
pub(crate) fn viewer_schema(s: &Value) -> Value {
    let Some(obj) = s.as_object() else {
        return match s {
            Value::Array(a) => Value::Array(a.iter().map(viewer_schema).collect()),
            other => other.clone(),
        };
    };
    let mut o = obj.clone();
    if let Some(Value::Array(types)) = o.get("type") {
        let t: Vec<&str> = types
            .iter()
            .filter_map(Value::as_str)
            .filter(|t| *t != "null")
            .collect();
        let one = if t.contains(&"string") {
            "string"
        } else {
            t.first().copied().unwrap_or("string")
        };
        o.insert("type".into(), Value::from(one));
    }
    for k in ["anyOf", "oneOf"] {
        let Some(Value::Array(alts)) = o.get(k) else {
            continue;
        };
        let alts: Vec<Value> = alts
            .iter()
            .map(viewer_schema)
            .filter(|a| a["type"] != "null")
            .collect();
        // An alternative the viewer is not told of: neither is it of the whole.
        if alts.iter().any(Value::is_null) {
            return Value::Null;
        }
        let scalar = |a: &Value| {
            matches!(
                a["type"].as_str(),
                Some("boolean" | "number" | "integer" | "string")
            )
        };
        if k == "oneOf" && alts.iter().all(|a| a["const"].is_number()) {
            o.insert(k.into(), Value::Array(alts));
        } else if alts
            .iter()
            .all(|a| a["const"].is_string() || a["enum"].is_array())
        {
            o.remove(k);
            o.insert("type".into(), Value::from("string"));
        } else if alts.len() > 1 && alts.iter().all(scalar) {
            // A value that is a flag, a number or a word by turns (a command in the
            // snapshot): no one type says it, so the viewer is not told of it (the
            // per-device channels carry the same as numbers).
            return Value::Null;
        } else if alts.len() == 1 {
            o.remove(k);
            if let Value::Object(a) = &alts[0] {
                for (key, v) in a {
                    o.insert(key.clone(), v.clone());
                }
            }
        }
    }
    if let Some(Value::Object(props)) = o.get("properties") {
        let p: serde_json::Map<String, Value> = props
            .iter()
            .map(|(n, v)| (n.clone(), viewer_schema(v)))
            .filter(|(_, v)| !v.is_null())
            .collect();
        if let Some(Value::Array(req)) = o.get("required") {
            let req: Vec<Value> = req
                .iter()
                .filter(|r| r.as_str().is_some_and(|r| p.contains_key(r)))
                .cloned()
                .collect();
            o.insert("required".into(), Value::Array(req));
        }
        o.insert("properties".into(), Value::Object(p));
    }
    if let Some(items) = o.get("items") {
        let items = viewer_schema(items);
        o.insert("items".into(), items);
    }
    Value::Object(o)
}

/// A message as viewers get it: every member whose value is null left out (a viewer
/// shows nothing for it either way), so that it validates against [`viewer_schema`].
pub(crate) fn without_nulls(payload: &[u8]) -> Vec<u8> {
    fn strip(v: &mut Value) {
        match v {
            Value::Object(m) => {
                m.retain(|_, x| !x.is_null());
                m.values_mut().for_each(strip);
            }
            Value::Array(a) => a.iter_mut().for_each(strip),
            _ => {}
        }
    }
    match serde_json::from_slice::<Value>(payload) {
        Ok(mut v) => {
            strip(&mut v);
            serde_json::to_vec(&v).unwrap_or_else(|_| payload.to_vec())
        }
        Err(_) => payload.to_vec(),
    }
}

/// Why Foxglove's and Lichtblick's JSON Schema reader (`parseJsonSchema` in their
/// `mcap-support`) would refuse `schema`, field by field, as it reads it; empty when it
/// takes it. The rules are that reader's, written again for the tests.
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn viewer_refuses(schema: &Value) -> Vec<String> {
    fn object(s: &Value, path: &str, out: &mut Vec<String>) {
        if s["type"] != "object" {
            out.push(format!("{path}: expected type object, got {}", s["type"]));
            return;
        }
        let Some(props) = s["properties"].as_object() else {
            return;
        };
        for (name, f) in props {
            let at = if path.is_empty() {
                name.clone()
            } else {
                format!("{path}.{name}")
            };
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

    #[test]
    fn either_subprotocol_is_answered_with_the_one_offered() {
        assert_eq!(choose(["foxglove.sdk.v1"]), Some("foxglove.sdk.v1"));
        assert_eq!(
            choose(["foxglove.websocket.v1"]),
            Some("foxglove.websocket.v1")
        );
        assert_eq!(
            choose(["x, foxglove.websocket.v1, foxglove.sdk.v1"]),
            Some("foxglove.websocket.v1")
        );
        assert_eq!(choose(["chat", "foxglove.sdk.v1"]), Some("foxglove.sdk.v1"));
        assert_eq!(choose(["foxglove.websocket.v2"]), None);
        assert_eq!(choose([]), None);
    }

    #[test]
    fn message_data_is_opcode_subscription_time_payload() {
        let b = message_data(7, 0x0102_0304_0506_0708, b"{}");
        assert_eq!(
            b,
            [1, 7, 0, 0, 0, 8, 7, 6, 5, 4, 3, 2, 1, b'{', b'}'].as_slice()
        );
    }

    #[test]
    fn subscribe_and_unsubscribe_parse() {
        assert_eq!(
            parse(
                r#"{"op":"subscribe","subscriptions":[{"id":0,"channelId":3},{"id":1,"channelId":5}]}"#
            ),
            Ok(ClientOp::Subscribe(vec![(0, 3), (1, 5)]))
        );
        assert_eq!(
            parse(r#"{"op":"unsubscribe","subscriptionIds":[0,1]}"#),
            Ok(ClientOp::Unsubscribe(vec![0, 1]))
        );
        assert_eq!(
            parse(r#"{"op":"advertise","channels":[]}"#),
            Ok(ClientOp::Other("advertise".into()))
        );
        assert!(parse(r#"{"op":"subscribe"}"#)
            .unwrap_err()
            .contains("subscriptions"));
        assert!(parse("[1]").unwrap_err().contains("`op`"));
    }

    #[test]
    fn server_info_claims_no_capability() {
        let v: serde_json::Value =
            serde_json::from_str(&server_info("adrive", "1", "alice")).unwrap();
        assert_eq!(v["op"], "serverInfo");
        assert_eq!(v["capabilities"], json!([]));
    }
}
