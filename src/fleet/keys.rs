//! The fleet's key expressions: every vehicle under `adrive/<id>`, its liveliness
//! token at that key and its state one level below; a link to it (a console or an
//! operator's command from elsewhere) under `adrive/<id>/link/<sid>`: the link's own
//! token there, what it sends at `…/up`, what it is sent at `…/down`. One place for
//! every name, so the member that publishes and the tools that read cannot drift
//! apart.

/// The root of every fleet key.
pub const ROOT: &str = "adrive";
/// Every vehicle's liveliness token.
pub const TOKENS: &str = "adrive/*";
/// Every vehicle's state.
pub const STATES: &str = "adrive/*/state";

/// The liveliness token of vehicle `id`.
pub fn token(id: &str) -> String {
    format!("{ROOT}/{id}")
}

/// Where vehicle `id` publishes its state.
pub fn state(id: &str) -> String {
    format!("{ROOT}/{id}/state")
}

/// Where vehicle `id` answers a ping (the fleet's round-trip time to it).
pub fn ping(id: &str) -> String {
    format!("{ROOT}/{id}/ping")
}

/// Every vehicle's ping.
pub const PINGS: &str = "adrive/*/ping";

/// The vehicle a ping's key names (`adrive/car1/ping` → `car1`).
pub fn id_of_ping(key: &str) -> Option<&str> {
    id_of_token(key.strip_suffix("/ping")?)
}

/// The liveliness token of link `sid` to vehicle `id`: the link is there as long as
/// it is.
pub fn link(id: &str, sid: &str) -> String {
    format!("{ROOT}/{id}/link/{sid}")
}

/// Every link's token to vehicle `id`.
pub fn links(id: &str) -> String {
    format!("{ROOT}/{id}/link/*")
}

/// What link `sid` sends vehicle `id`.
pub fn up(id: &str, sid: &str) -> String {
    format!("{ROOT}/{id}/link/{sid}/up")
}

/// What every link sends vehicle `id`.
pub fn ups(id: &str) -> String {
    format!("{ROOT}/{id}/link/*/up")
}

/// What vehicle `id` sends link `sid`.
pub fn down(id: &str, sid: &str) -> String {
    format!("{ROOT}/{id}/link/{sid}/down")
}

/// The link a key of vehicle `id` names: its token's (`adrive/car1/link/ab12` → `ab12`),
/// or with `suffix` `/up`, what it sends.
pub fn sid_of<'a>(id: &str, key: &'a str, suffix: &str) -> Option<&'a str> {
    let sid = key
        .strip_prefix(ROOT)?
        .strip_prefix('/')?
        .strip_prefix(id)?
        .strip_prefix("/link/")?
        .strip_suffix(suffix)?;
    (!sid.is_empty() && !sid.contains('/')).then_some(sid)
}

/// The vehicle a token's key names (`adrive/car1` → `car1`).
pub fn id_of_token(key: &str) -> Option<&str> {
    let id = key.strip_prefix(ROOT)?.strip_prefix('/')?;
    (!id.is_empty() && !id.contains('/')).then_some(id)
}

/// The vehicle a state's key names (`adrive/car1/state` → `car1`).
pub fn id_of_state(key: &str) -> Option<&str> {
    id_of_token(key.strip_suffix("/state")?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_name_their_vehicle_and_nothing_else() {
        assert_eq!(id_of_token(&token("car1")), Some("car1"));
        assert_eq!(id_of_state(&state("car1")), Some("car1"));
        assert_eq!(id_of_token("adrive/car1/state"), None);
        assert_eq!(id_of_token("adrive/"), None);
        assert_eq!(id_of_token("adrivex/car1"), None);
        assert_eq!(id_of_state(&link("car1", "ab")), None);
        assert_eq!(id_of_ping(&ping("car1")), Some("car1"));
        assert_eq!(id_of_ping(&state("car1")), None);
        assert_eq!(id_of_token(&up("car1", "ab")), None);
        assert_eq!(sid_of("car1", &link("car1", "ab"), ""), Some("ab"));
        assert_eq!(sid_of("car1", &up("car1", "ab"), "/up"), Some("ab"));
        assert_eq!(sid_of("car1", &up("car1", "ab"), ""), None);
        assert_eq!(sid_of("car2", &link("car1", "ab"), ""), None);
        assert_eq!(sid_of("car", &link("car1", "ab"), ""), None);
        assert_eq!(sid_of("car1", &down("car1", "ab"), "/up"), None);
        assert_eq!(id_of_state("adrive/a/b/state"), None);
    }
}
