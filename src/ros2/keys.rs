//! How rmw_zenoh names things on a Zenoh network, as pure functions over strings and
//! bytes: the key expression of a topic or service, the liveliness token that announces
//! a node, publisher, subscription or service to the ROS graph, the GID that rmw_zenoh
//! derives from a token, and the attachment every message carries. The layouts are
//! those of rmw_zenoh's design document (`docs/design.md`) and its
//! `liveliness_utils.cpp` / `attachment_helpers.cpp`:
//!
//! - topic: `<domain>/<fully qualified name without the outer />/<DDS type>/<type hash>`,
//!   `0/alice/vehicle/status/steering_status/autoware_vehicle_msgs::msg::dds_::SteeringReport_/RIHS01_…`;
//! - token: `@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<NN|MP|MS|SS|SC>/<enclave>/
//!   <namespace>/<node>[/<topic>/<DDS type>/<hash>/<qos>]`, names mangled (`/` → `%`);
//! - GID: XXH3-128 of the token's key expression, low 64 bits then high, little-endian;
//! - attachment: sequence number (i64 LE), source timestamp (ns since the epoch, i64
//!   LE), the GID's length (one byte, 16) and the GID.

use std::fmt;

/// The prefix of every ROS 2 liveliness token.
pub(crate) const ADMIN_SPACE: &str = "@ros2_lv";
/// The length of a GID.
pub(crate) const GID_LEN: usize = 16;
/// The length of an attachment.
pub(crate) const ATTACHMENT_LEN: usize = 8 + 8 + 1 + GID_LEN;
/// A default QoS (reliable, volatile, keep last 10), as rmw_zenoh writes it: each
/// policy left empty when it is the default.
pub const DEFAULT_QOS: &str = "::,:,:,:,,";

/// A publisher's (or client's) id in the ROS graph.
pub(crate) type Gid = [u8; GID_LEN];

/// What a liveliness token announces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Entity {
    Node,
    Publisher,
    Subscription,
    Service,
    Client,
}

impl Entity {
    pub fn code(self) -> &'static str {
        match self {
            Entity::Node => "NN",
            Entity::Publisher => "MP",
            Entity::Subscription => "MS",
            Entity::Service => "SS",
            Entity::Client => "SC",
        }
    }

    fn from_code(code: &str) -> Option<Entity> {
        [
            Entity::Node,
            Entity::Publisher,
            Entity::Subscription,
            Entity::Service,
            Entity::Client,
        ]
        .into_iter()
        .find(|e| e.code() == code)
    }
}

/// A ROS interface type: `autoware_vehicle_msgs/msg/SteeringReport` and its RIHS01 hash.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TypeInfo {
    /// `package/msg/Name` or `package/srv/Name`.
    pub name: &'static str,
    /// `RIHS01_` and 64 hex digits.
    pub hash: &'static str,
}

impl TypeInfo {
    /// The name as DDS declares it: `autoware_vehicle_msgs::msg::dds_::SteeringReport_`.
    pub(crate) fn dds_name(&self) -> String {
        let mut parts: Vec<&str> = self.name.split('/').collect();
        let last = parts.pop().unwrap_or_default();
        format!("{}::dds_::{last}_", parts.join("::"))
    }
}

/// `/` → `%`, as rmw_zenoh mangles names inside a token.
pub(crate) fn mangle(name: &str) -> String {
    name.replace('/', "%")
}

/// `%` → `/`.
pub(crate) fn demangle(name: &str) -> String {
    name.replace('%', "/")
}

/// A topic or service name joined to a namespace: `/alice` + `vehicle/status/x` is
/// `/alice/vehicle/status/x`; `/` + `diagnostics` is `/diagnostics`.
pub fn qualified(namespace: &str, name: &str) -> String {
    let ns = namespace.trim_end_matches('/');
    format!("{ns}/{}", name.trim_start_matches('/'))
}

/// The Zenoh key expression of a topic or service, as rmw_zenoh declares it.
pub fn topic_key(domain: u32, qualified_name: &str, ty: &TypeInfo) -> String {
    format!(
        "{domain}/{}/{}/{}",
        qualified_name.trim_matches('/'),
        ty.dds_name(),
        ty.hash
    )
}

/// The node a token belongs to.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct NodeInfo {
    pub domain: u32,
    /// The Zenoh session id, as Zenoh prints it.
    pub zid: String,
    pub node_id: u32,
    /// `/alice`, or `/` for none.
    pub namespace: String,
    pub name: String,
    /// The security enclave, `/` unless set.
    pub enclave: String,
}

impl NodeInfo {
    /// `/alice/adrive`.
    pub fn fqn(&self) -> String {
        qualified(&self.namespace, &self.name)
    }
}

/// A liveliness token's key expression: the node's own (`entity` = [`Entity::Node`],
/// `topic` = None), or one of its publishers, subscriptions, services or clients.
pub fn token(
    node: &NodeInfo,
    entity_id: u32,
    entity: Entity,
    topic: Option<(&str, &TypeInfo, &str)>,
) -> String {
    let mut t = format!(
        "{ADMIN_SPACE}/{}/{}/{}/{}/{}/{}/{}/{}",
        node.domain,
        node.zid,
        node.node_id,
        entity_id,
        entity.code(),
        mangle(&node.enclave),
        mangle(&node.namespace),
        mangle(&node.name),
    );
    if let Some((name, ty, qos)) = topic {
        t.push_str(&format!(
            "/{}/{}/{}/{qos}",
            mangle(name),
            ty.dds_name(),
            ty.hash
        ));
    }
    t
}

/// A token read back: which node, which entity, on which topic.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct Token {
    pub node: NodeInfo,
    pub(crate) entity_id: u32,
    pub(crate) entity: Entity,
    /// The topic or service (demangled), its DDS type and hash.
    pub topic: Option<(String, String, String)>,
}

/// Parse a liveliness token's key expression; None when it is not one.
pub(crate) fn parse_token(key: &str) -> Option<Token> {
    let parts: Vec<&str> = key.split('/').collect();
    if parts.len() < 9 || parts[0] != ADMIN_SPACE || parts.iter().any(|p| p.is_empty()) {
        return None;
    }
    let entity = Entity::from_code(parts[5])?;
    let topic = match (entity, parts.len()) {
        (Entity::Node, 9) => None,
        (Entity::Node, _) => return None,
        (_, 13) => Some((
            demangle(parts[9]),
            parts[10].to_string(),
            parts[11].to_string(),
        )),
        _ => return None,
    };
    Some(Token {
        node: NodeInfo {
            domain: parts[1].parse().ok()?,
            zid: parts[2].to_string(),
            node_id: parts[3].parse().ok()?,
            enclave: demangle(parts[6]),
            namespace: demangle(parts[7]),
            name: demangle(parts[8]),
        },
        entity_id: parts[4].parse().ok()?,
        entity,
        topic,
    })
}

/// The GID rmw_zenoh gives the entity of a token: XXH3-128 of its key expression, the
/// low 64 bits then the high 64 bits, little-endian.
pub fn gid(token_key: &str) -> Gid {
    xxhash_rust::xxh3::xxh3_128(token_key.as_bytes()).to_le_bytes()
}

/// The metadata rmw_zenoh attaches to every message, request and reply.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Attachment {
    /// Counts the publisher's messages from 1 (a client's requests; a reply repeats
    /// its request's).
    pub sequence_number: i64,
    /// When it was sent: nanoseconds since the Unix epoch.
    pub source_timestamp: i64,
    /// The publisher (or client) GID.
    pub gid: Gid,
}

/// Why an attachment could not be read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BadAttachment(pub usize);

impl fmt::Display for BadAttachment {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "an rmw_zenoh attachment is {ATTACHMENT_LEN} bytes (sequence number, timestamp, \
             GID of 16), got {}",
            self.0
        )
    }
}

impl Attachment {
    pub fn encode(&self) -> [u8; ATTACHMENT_LEN] {
        let mut out = [0u8; ATTACHMENT_LEN];
        out[..8].copy_from_slice(&self.sequence_number.to_le_bytes());
        out[8..16].copy_from_slice(&self.source_timestamp.to_le_bytes());
        out[16] = GID_LEN as u8;
        out[17..].copy_from_slice(&self.gid);
        out
    }

    pub fn decode(bytes: &[u8]) -> Result<Attachment, BadAttachment> {
        if bytes.len() != ATTACHMENT_LEN || bytes[16] as usize != GID_LEN {
            return Err(BadAttachment(bytes.len()));
        }
        let i64_at = |i: usize| i64::from_le_bytes(bytes[i..i + 8].try_into().expect("8 bytes"));
        Ok(Attachment {
            sequence_number: i64_at(0),
            source_timestamp: i64_at(8),
            gid: bytes[17..].try_into().expect("16 bytes"),
        })
    }
}

/// Nanoseconds since the Unix epoch, now.
pub(crate) fn now_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i64)
}

#[cfg(test)]
mod tests {
    use super::*;

    const STRING: TypeInfo = TypeInfo {
        name: "std_msgs/msg/String",
        hash: "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    };

    #[test]
    fn keys_and_tokens_are_those_of_the_rmw_zenoh_design_document() {
        // The examples of rmw_zenoh's docs/design.md.
        assert_eq!(
            topic_key(0, "/robot1/chatter", &STRING),
            "0/robot1/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
        );
        let talker = NodeInfo {
            domain: 2,
            zid: "8b20917502ee955ac4476e0266340d5c".into(),
            node_id: 0,
            namespace: "/".into(),
            name: "talker".into(),
            enclave: "/".into(),
        };
        let key = token(
            &talker,
            10,
            Entity::Publisher,
            Some(("/chatter", &STRING, "::,7:,:,:,,")),
        );
        assert_eq!(
            key,
            "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,"
        );
        let back = parse_token(&key).unwrap();
        assert_eq!(back.node, talker);
        assert_eq!(back.entity, Entity::Publisher);
        assert_eq!(back.topic.unwrap().0, "/chatter");
        assert_eq!(
            token(&talker, 0, Entity::Node, None),
            "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/0/NN/%/%/talker"
        );
        assert!(parse_token("@ros2_lv/2/x/0/0/NN/%/%").is_none());
        assert!(parse_token("0/chatter/x/y").is_none());
    }

    #[test]
    fn an_attachment_round_trips_and_refuses_other_lengths() {
        let a = Attachment {
            sequence_number: 7,
            source_timestamp: 1_700_000_000_123_456_789,
            gid: [3; GID_LEN],
        };
        let bytes = a.encode();
        assert_eq!(bytes[..8], 7i64.to_le_bytes());
        assert_eq!(bytes[16], 16);
        assert_eq!(Attachment::decode(&bytes), Ok(a));
        assert_eq!(Attachment::decode(&bytes[1..]), Err(BadAttachment(32)));
    }

    #[test]
    fn qualified_names_join_namespaces() {
        assert_eq!(
            qualified("/alice", "vehicle/status/x"),
            "/alice/vehicle/status/x"
        );
        assert_eq!(qualified("/", "diagnostics"), "/diagnostics");
    }
}
