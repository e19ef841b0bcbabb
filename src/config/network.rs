//! The `[network]` section of a vehicle file: where the command listener binds, who
//! may send, whether the network may engage, the watchdog, and where the state
//! broadcast goes. Every key has a default, so a vehicle file without the section gets
//! a loopback-only listener that cannot engage.

use crate::config::limits::{self, Violation};
use serde::{Deserialize, Deserializer};
use std::fmt;
use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;
use std::str::FromStr;
use std::time::Duration;

/// The command listener's default address (the paper's "Skynet key" 47576).
pub(crate) const DEFAULT_LISTEN: &str = "127.0.0.1:47576";
/// Where the state broadcast goes by default.
pub(crate) const DEFAULT_BROADCAST: &str = "127.0.0.1:47577";
/// The listener's port when `--listen` names only an address.
pub(crate) const DEFAULT_PORT: u16 = 47576;

/// `[network]`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NetworkConfig {
    /// Where the command listener binds (`--listen` overrides it).
    #[serde(deserialize_with = "listen")]
    pub listen: SocketAddr,
    /// May a network sender engage the vehicle? Off unless the vehicle file says so.
    pub allow_engage: bool,
    /// While engaged by the network, no valid command for this long (or a frozen
    /// rolling counter) brings the vehicle to the safe state and disengages it.
    #[serde(deserialize_with = "crate::config::duration")]
    pub watchdog_timeout: Duration,
    /// Destinations of the state broadcast: unicast addresses and/or multicast groups.
    #[serde(deserialize_with = "destinations")]
    pub broadcast_to: Vec<SocketAddr>,
    /// State broadcasts per second.
    pub broadcast_rate: f64,
    /// Time-to-live of multicast broadcasts (1: this subnet only).
    pub multicast_ttl: u32,
    /// Senders allowed to command: IP addresses (any port) or `ip:port`. Empty: any
    /// sender that can reach the listener.
    pub allow: Vec<Allow>,
    /// A shared key file; when set, every datagram must be signed (HMAC-SHA256) and
    /// carry a strictly increasing `seq`. Relative to the vehicle file's directory.
    pub key_file: Option<PathBuf>,
    /// Answer refusals (and engage / disengage) with a datagram to the sender.
    pub replies: bool,
}

impl Default for NetworkConfig {
    fn default() -> Self {
        NetworkConfig {
            listen: DEFAULT_LISTEN.parse().expect("valid address"),
            allow_engage: false,
            watchdog_timeout: limits::WATCHDOG_TIMEOUT.default_value(),
            broadcast_to: vec![DEFAULT_BROADCAST.parse().expect("valid address")],
            broadcast_rate: limits::BROADCAST_RATE.default_value(),
            multicast_ttl: limits::MULTICAST_TTL.default_value() as u32,
            allow: Vec::new(),
            key_file: None,
            replies: true,
        }
    }
}

impl NetworkConfig {
    /// Every value within its limit.
    pub fn check(&self) -> Result<(), Violation> {
        limits::WATCHDOG_TIMEOUT.check(self.watchdog_timeout)?;
        limits::BROADCAST_RATE.check(self.broadcast_rate)?;
        limits::MULTICAST_TTL.check(u64::from(self.multicast_ttl))?;
        Ok(())
    }

    /// Is `from` allowed to send commands?
    pub fn allows(&self, from: SocketAddr) -> bool {
        self.allow.is_empty() || self.allow.iter().any(|a| a.matches(from))
    }

    /// The time between two state broadcasts.
    pub(crate) fn broadcast_period(&self) -> Duration {
        Duration::from_secs_f64(1.0 / self.broadcast_rate)
    }
}

/// One allow-list entry: an IP address (any port) or an exact `ip:port`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Allow {
    Ip(IpAddr),
    Addr(SocketAddr),
}

impl Allow {
    pub fn matches(&self, from: SocketAddr) -> bool {
        let ip = canonical(from.ip());
        match *self {
            Allow::Ip(a) => canonical(a) == ip,
            Allow::Addr(a) => canonical(a.ip()) == ip && a.port() == from.port(),
        }
    }
}

/// An IPv4 address seen through an IPv6 socket (`::ffff:a.b.c.d`) is that IPv4 address.
fn canonical(ip: IpAddr) -> IpAddr {
    match ip {
        IpAddr::V6(v6) => v6
            .to_ipv4_mapped()
            .map(IpAddr::V4)
            .unwrap_or(IpAddr::V6(v6)),
        v4 => v4,
    }
}

impl FromStr for Allow {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let s = s.trim();
        if let Ok(a) = s.parse::<SocketAddr>() {
            return Ok(Allow::Addr(a));
        }
        if let Ok(ip) = s.parse::<IpAddr>() {
            return Ok(Allow::Ip(ip));
        }
        let form = "expected an IP address or host (\"10.0.0.5\", \"planner.local\") or \
                    address:port (\"10.0.0.5:9000\")";
        match s.rsplit_once(':') {
            Some((host, port)) if port.parse::<u16>().is_ok() => {
                resolve(host, port.parse().unwrap_or(0), form).map(Allow::Addr)
            }
            _ => resolve(s, 0, form).map(|a| Allow::Ip(a.ip())),
        }
    }
}

impl fmt::Display for Allow {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Allow::Ip(ip) => write!(f, "{ip}"),
            Allow::Addr(a) => write!(f, "{a}"),
        }
    }
}

impl<'de> Deserialize<'de> for Allow {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        String::deserialize(d)?
            .parse()
            .map_err(serde::de::Error::custom)
    }
}

fn listen<'de, D: Deserializer<'de>>(d: D) -> Result<SocketAddr, D::Error> {
    parse_listen(&String::deserialize(d)?).map_err(serde::de::Error::custom)
}

fn destinations<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<SocketAddr>, D::Error> {
    Vec::<String>::deserialize(d)?
        .iter()
        .map(|s| parse_destination(s).map_err(serde::de::Error::custom))
        .collect()
}

/// The one reading of an address a person writes, for every flag and key that takes
/// one: `IP:PORT` (`127.0.0.1:47576`, `[::1]:47576`) or `HOST:PORT` (`localhost:47576`,
/// resolved now, an IPv4 address preferred); with `default_port`, an IP or a host alone
/// too. `form` says what is expected, for the error.
fn parse_addr(s: &str, default_port: Option<u16>, form: &str) -> Result<SocketAddr, String> {
    let s = s.trim();
    if let Ok(a) = s.parse::<SocketAddr>() {
        return Ok(a);
    }
    if let (Ok(ip), Some(port)) = (s.parse::<IpAddr>(), default_port) {
        return Ok(SocketAddr::new(ip, port));
    }
    match s.rsplit_once(':') {
        Some((host, port)) if !host.is_empty() && !host.contains(':') => {
            let port = port
                .parse::<u16>()
                .map_err(|_| format!("{form}, got {s:?}: the port {port:?} is not 0 to 65535"))?;
            resolve(host, port, form)
        }
        None if !s.is_empty() => match default_port {
            Some(port) => resolve(s, port, form),
            None => Err(format!("{form}, got {s:?}: give the port")),
        },
        _ => Err(format!("{form}, got {s:?}")),
    }
}

/// `host`'s address (an IPv4 one if it has any) with `port`. Only a host name is looked
/// up (letters, digits, `-` and `.`, with a letter): `10.0.0` is a mistyped address,
/// not a name.
fn resolve(host: &str, port: u16, form: &str) -> Result<SocketAddr, String> {
    use std::net::ToSocketAddrs;
    let name = host
        .chars()
        .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '.')
        && host.chars().any(|c| c.is_ascii_alphabetic())
        && !host.starts_with(['-', '.']);
    if !name {
        return Err(format!("{form}, got {host:?}"));
    }
    let found: Vec<SocketAddr> = (host, port)
        .to_socket_addrs()
        .map_err(|e| format!("{form}, got {host:?}: no such host ({e})"))?
        .collect();
    found
        .iter()
        .find(|a| a.is_ipv4())
        .or(found.first())
        .copied()
        .ok_or_else(|| format!("{form}, got {host:?}: the host has no address"))
}

/// `--listen ADDR`, `[network] listen`: where this adrive takes commands.
pub(crate) fn parse_listen(s: &str) -> Result<SocketAddr, String> {
    parse_addr(
        s,
        Some(DEFAULT_PORT),
        &format!(
            "expected IP:PORT or HOST:PORT, or an IP or host alone for port {DEFAULT_PORT} \
             (\"127.0.0.1:{DEFAULT_PORT}\", \"localhost:{DEFAULT_PORT}\", \"0.0.0.0\")"
        ),
    )
}

/// An address another program listens on or a broadcast goes to (`send --to`,
/// `watch --from`, `--broadcast-to`, `[network] broadcast_to`, `replay --broadcast`,
/// `--foxglove`): `IP:PORT` or `HOST:PORT`, or a multicast group.
pub(crate) fn parse_destination(s: &str) -> Result<SocketAddr, String> {
    parse_addr(
        s,
        None,
        "expected IP:PORT or HOST:PORT, a unicast address or a multicast group \
         (\"127.0.0.1:47577\", \"localhost:47577\", \"239.255.0.1:47577\")",
    )
}

/// `adrive send --to`: where an adrive takes commands (its `--listen`).
pub(crate) fn parse_peer(s: &str) -> Result<SocketAddr, String> {
    parse_addr(
        s,
        None,
        "expected the adrive's --listen address, IP:PORT or HOST:PORT \
         (\"127.0.0.1:47576\", \"localhost:47576\")",
    )
}

/// `--foxglove ADDR`: where this adrive serves the live view.
pub(crate) fn parse_serve(s: &str) -> Result<SocketAddr, String> {
    parse_addr(
        s,
        None,
        "expected an address of this host, IP:PORT or HOST:PORT \
         (\"127.0.0.1:8765\", \"localhost:8765\", port 0: any free port)",
    )
}

/// Why binding `addr` failed, for a person: `what` names the flag or key (`--listen`),
/// `means` what it is for. An address that is not this host's (os error 99) is the
/// usual mistake: the flag wants an address of this host.
pub(crate) fn bind_error(what: &str, addr: SocketAddr, means: &str, e: &std::io::Error) -> String {
    match e.kind() {
        std::io::ErrorKind::AddrNotAvailable => format!(
            "{what} {addr}: {} is not an address of this host; {means}",
            addr.ip()
        ),
        std::io::ErrorKind::AddrInUse => format!(
            "{what} {addr}: the port is in use by another program (another adrive?); {means}"
        ),
        std::io::ErrorKind::PermissionDenied => {
            format!("{what} {addr}: permission denied (ports below 1024 need privileges); {means}")
        }
        _ => format!("{what} {addr}: {e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_loopback_and_no_network_engage() {
        let c = NetworkConfig::default();
        assert_eq!(c.listen.to_string(), "127.0.0.1:47576");
        assert_eq!(c.broadcast_to[0].to_string(), "127.0.0.1:47577");
        assert!(!c.allow_engage);
        assert_eq!(c.watchdog_timeout, Duration::from_millis(500));
        assert_eq!(c.broadcast_period(), Duration::from_millis(100));
        assert!(c.check().is_ok());
        assert!(c.allows("10.1.2.3:4".parse().unwrap()));
    }

    #[test]
    fn allow_list_by_ip_or_exact_address() {
        let c = NetworkConfig {
            allow: vec![
                "10.0.0.5".parse().unwrap(),
                "127.0.0.1:9000".parse().unwrap(),
            ],
            ..NetworkConfig::default()
        };
        assert!(c.allows("10.0.0.5:1234".parse().unwrap()));
        assert!(c.allows("[::ffff:10.0.0.5]:1".parse().unwrap()));
        assert!(c.allows("127.0.0.1:9000".parse().unwrap()));
        assert!(!c.allows("127.0.0.1:9001".parse().unwrap()));
        assert!(!c.allows("10.0.0.6:1234".parse().unwrap()));
        assert!("10.0.0".parse::<Allow>().is_err());
    }

    #[test]
    fn listen_takes_an_address_with_or_without_port() {
        assert_eq!(
            parse_listen("0.0.0.0").unwrap().to_string(),
            "0.0.0.0:47576"
        );
        assert_eq!(
            parse_listen("10.0.0.1:9").unwrap().to_string(),
            "10.0.0.1:9"
        );
        assert!(parse_listen("anywhere.invalid").is_err());
    }

    /// The incident: `--to localhost:47576` and `--listen localhost:…` were refused as
    /// "invalid socket address syntax". Every flag and key that takes an address reads
    /// it the one way: a host name is looked up.
    #[test]
    fn a_host_name_is_resolved_wherever_an_address_is_taken() {
        let local: SocketAddr = "127.0.0.1:47576".parse().unwrap();
        assert_eq!(parse_listen("localhost:47576"), Ok(local));
        assert_eq!(parse_listen("localhost"), Ok(local));
        assert_eq!(
            parse_destination("localhost:47577").unwrap().to_string(),
            "127.0.0.1:47577"
        );
        assert_eq!(
            "localhost".parse::<Allow>(),
            Ok(Allow::Ip("127.0.0.1".parse().unwrap()))
        );
        assert_eq!(
            "localhost:9000".parse::<Allow>(),
            Ok(Allow::Addr("127.0.0.1:9000".parse().unwrap()))
        );
        let e = parse_destination("localhost").unwrap_err();
        assert!(e.ends_with("got \"localhost\": give the port"), "{e}");
        let e = parse_destination("localhost:http").unwrap_err();
        assert!(e.contains("the port \"http\" is not 0 to 65535"), "{e}");
        let e = parse_destination("10.0.0:5").unwrap_err();
        assert!(e.starts_with("expected IP:PORT or HOST:PORT"), "{e}");
        let e = parse_listen("no-such-host.invalid:1").unwrap_err();
        assert!(e.contains("\"no-such-host.invalid\": no such host"), "{e}");
        let vehicle = crate::config::parse(
            "[vehicle]\nname = \"x\"\n[network]\nlisten = \"localhost:9\"\nbroadcast_to = [\"localhost:10\"]\nallow = [\"localhost\"]\n",
            "v.toml",
        )
        .unwrap();
        assert_eq!(vehicle.network.listen.to_string(), "127.0.0.1:9");
        assert_eq!(vehicle.network.broadcast_to[0].to_string(), "127.0.0.1:10");
        assert!(vehicle.network.allows("127.0.0.1:5".parse().unwrap()));
    }

    #[test]
    fn a_bind_error_says_what_the_address_is_for() {
        let addr: SocketAddr = "10.9.9.9:47577".parse().unwrap();
        let e = std::io::Error::from(std::io::ErrorKind::AddrNotAvailable);
        assert_eq!(
            bind_error("--from", addr, "it is where the broadcast is sent to", &e),
            "--from 10.9.9.9:47577: 10.9.9.9 is not an address of this host; it is where the broadcast is sent to"
        );
    }

    #[test]
    fn network_section_errors_name_file_and_line() {
        let base = "[vehicle]\nname = \"x\"\n\n[network]\n";
        let err = |extra: &str| {
            crate::config::parse(&format!("{base}{extra}"), "v.toml")
                .unwrap_err()
                .to_string()
        };
        let e = err("listen = \"localhost-ish\"\n");
        assert!(
            e.starts_with("v.toml:5: [network] listen: expected IP:PORT")
                && e.contains("localhost-ish"),
            "{e}"
        );
        let e = err("broadcast_to = [\"127.0.0.1\"]\n");
        assert!(
            e.starts_with("v.toml:5: [network] broadcast_to: expected IP:PORT or HOST:PORT"),
            "{e}"
        );
        let e = err("allow = [\"10.0.0\"]\n");
        assert!(
            e.starts_with("v.toml:5: ") && e.contains("IP address"),
            "{e}"
        );
        let e = err("watchdog = \"1s\"\n");
        assert!(
            e.starts_with("v.toml:5: ") && e.contains("watchdog_timeout"),
            "{e}"
        );
        let e = err("watchdog_timeout = \"0ms\"\n");
        assert!(
            e.starts_with("v.toml:5: [network] watchdog_timeout: expected a duration"),
            "{e}"
        );
        let e = err("broadcast_rate = 0.0\n");
        assert!(e.contains("broadcast_rate"), "{e}");
        let ok = crate::config::parse(&format!("{base}allow_engage = true\n"), "v.toml").unwrap();
        assert!(ok.network.allow_engage);
        assert_eq!(ok.network.watchdog_timeout, Duration::from_millis(500));
        let alice = crate::config::VehicleConfig::alice();
        assert!(alice.network.allow_engage);
    }
}
