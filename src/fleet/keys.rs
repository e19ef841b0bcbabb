//! The fleet's key expressions: every vehicle under `adrive/<id>`, its liveliness
//! token at that key and its state one level below. One place for every name, so the
//! member that publishes and the tools that read cannot drift apart.

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

/// Where vehicle `id` answers the control socket's operations (watching only, so far).
pub fn ctl(id: &str) -> String {
    format!("{ROOT}/{id}/ctl")
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
        assert_eq!(id_of_state(&ctl("car1")), None);
        assert_eq!(id_of_token(&ctl("car1")), None);
        assert_eq!(id_of_state("adrive/a/b/state"), None);
    }
}
