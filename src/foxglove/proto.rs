//! The Foxglove WebSocket protocol, as much of it as a read-only live view speaks
//! (`foxglove/ws-protocol`, `docs/spec.md`): the subprotocol names, the server's JSON
//! messages (`serverInfo`, `advertise`, `status`), the binary message data frame and
//! the client's `subscribe` / `unsubscribe`. Pure functions over text and bytes.

use serde::Deserialize;
use serde_json::json;

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
pub(crate) struct Channel<'a> {
    pub id: u32,
    pub topic: &'a str,
    pub(crate) schema_name: &'a str,
    /// The JSON Schema, as text.
    pub schema: &'a str,
}

/// `advertise`: the channels, JSON messages with JSON Schemas.
pub(crate) fn advertise(channels: &[Channel]) -> String {
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
pub(crate) fn status(level: u8, message: &str) -> String {
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
pub(crate) enum ClientOp {
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
pub(crate) fn parse(text: &str) -> Result<ClientOp, String> {
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
