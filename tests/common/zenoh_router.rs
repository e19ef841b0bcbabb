//! A Zenoh router run by the test itself (the zenoh crate in router mode), on a
//! loopback port free right now, multicast scouting off: the fleet's network, which
//! never meets another one.

use zenoh::Wait;

/// The router's session (it routes while the session lives) and its endpoint.
pub fn start() -> (zenoh::Session, String) {
    let endpoint = free_endpoint();
    (start_on(&endpoint), endpoint)
}

/// A loopback endpoint whose port is free right now.
pub fn free_endpoint() -> String {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    format!("tcp/127.0.0.1:{port}")
}

/// A router on `endpoint` (again, after one there stopped).
pub fn start_on(endpoint: &str) -> zenoh::Session {
    let mut c = zenoh::Config::default();
    c.insert_json5("mode", "\"router\"").unwrap();
    c.insert_json5("listen/endpoints", &format!("[\"{endpoint}\"]"))
        .unwrap();
    c.insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    zenoh::open(c)
        .wait()
        .unwrap_or_else(|e| panic!("a Zenoh router on {endpoint}: {e}"))
}
