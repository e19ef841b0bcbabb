//! The ELM327 driver: engine data (rpm, road speed, coolant temperature) from the car's
//! OBD-II port through the ubiquitous ELM327 serial adapter. It is the modern stand-in
//! for the paper's OBD-II sensor: the supervisor watches `running` to detect a stall.
//! The reply parsing lives in [`proto`]; the simulated adapter is
//! [`crate::sim::elm327`].
//!
//! `open` brings the adapter to a known state: `ATZ` (reset; the banner takes about a
//! second), `ATE0` (echo off), `ATL0` (linefeeds off), `ATH0` (headers off), `ATSP0`
//! (find the car's protocol automatically). Spaces are left as the adapter has them
//! (`ATS` is missing on some clones) and the parser reads both forms; echo and linefeeds
//! are still tolerated should an adapter ignore the commands.
//!
//! `poll` asks for rpm and speed every time, one PID per request, and for coolant
//! temperature only on every [`COOLANT_EVERY`]th poll (the paper's "slow updates": it
//! changes over minutes); between, the last coolant value is reported. The first request
//! after `open` may make the adapter search the protocols, so it waits up to
//! [`SEARCH_TIMEOUT`]. `running` is `rpm >` [`RUNNING_RPM`].

pub(crate) mod proto;

use self::proto::{ElmError, Pid};
use super::{read_until, send_request, Driver, DriverError, Link};
use crate::config::protocol_map::ElmMap;
use crate::value::{Command, Reading};
use std::time::Duration;

/// How long `ATZ` may take to answer with its banner and prompt.
pub(crate) const RESET_TIMEOUT: Duration = Duration::from_millis(1500);
/// How long the first OBD request after `open` may take: the adapter searches the
/// car's protocols ([`super::protocol_search`]).
pub(crate) const SEARCH_TIMEOUT: Duration = Duration::from_secs(10);

/// Coolant temperature is read on one poll in this many.
pub(crate) const COOLANT_EVERY: u64 = 10;
/// Above this engine speed the engine counts as running (a cranking starter turns it
/// at 150–250 rpm; a warm idle is 600–900).
pub(crate) const RUNNING_RPM: f64 = 300.0;
/// Longest reply accepted before the prompt.
const MAX_REPLY: usize = 1024;

/// The commands `open` sends after `ATZ`, each answered by `OK`.
pub const INIT: [&str; 4] = ["ATE0", "ATL0", "ATH0", "ATSP0"];

/// Host side of an ELM327 OBD-II adapter.
pub(crate) struct Elm327Driver {
    map: ElmMap,
    reply_timeout: Duration,
    searched: bool,
    polls: u64,
    coolant: Option<f64>,
    banner: Option<String>,
}

impl Elm327Driver {
    /// A driver that waits up to `reply_timeout` for each OBD answer (an ELM327 gives
    /// up on a silent car after about 200 ms by itself and says `NO DATA`).
    pub(crate) fn new(map: ElmMap, reply_timeout: Duration) -> Elm327Driver {
        Elm327Driver {
            map,
            reply_timeout,
            searched: false,
            polls: 0,
            coolant: None,
            banner: None,
        }
    }

    /// The adapter's identification from the last reset, e.g. `ELM327 v1.5`.
    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) fn banner(&self) -> Option<&str> {
        self.banner.as_deref()
    }

    /// Send one command line and read the reply up to the prompt; the exchange is over
    /// `timeout` after the request went out, whatever the adapter sends meanwhile.
    fn transact(
        &mut self,
        link: &mut dyn Link,
        command: &str,
        timeout: Duration,
    ) -> Result<Vec<u8>, DriverError> {
        let deadline = send_request(link, format!("{command}\r").as_bytes(), timeout)?;
        let mut reply = Vec::with_capacity(64);
        read_until(link, &mut reply, proto::PROMPT, MAX_REPLY, &deadline)?;
        Ok(reply)
    }

    fn read_pid(&mut self, link: &mut dyn Link, pid: Pid) -> Result<f64, DriverError> {
        let timeout = if self.searched {
            self.reply_timeout
        } else {
            SEARCH_TIMEOUT
        };
        let request = pid.request();
        let reply = self.transact(link, request.trim_end(), timeout)?;
        self.searched = true;
        proto::parse_pid(&reply, pid).map_err(|e| elm_error(&format!("{pid}"), e))
    }
}

fn elm_error(what: &str, e: ElmError) -> DriverError {
    match e {
        ElmError::Garbled(why) => DriverError::Garbled(format!("{what}: {why}")),
        e => DriverError::Refused(format!("{what}: {e}")),
    }
}

impl Driver for Elm327Driver {
    fn longest(&self) -> Duration {
        // A reopen (the reset, the settings), then a poll whose first request searches
        // the car's protocols and whose others are answered in the reply timeout.
        RESET_TIMEOUT
            + self.reply_timeout * INIT.len() as u32
            + SEARCH_TIMEOUT
            + self.reply_timeout * 2
    }

    fn open(&mut self, link: &mut dyn Link) -> Result<(), DriverError> {
        self.searched = false;
        self.polls = 0;
        self.coolant = None;
        let reply = self.transact(link, "ATZ", RESET_TIMEOUT)?;
        self.banner = Some(proto::parse_banner(&reply).map_err(|e| elm_error("ATZ", e))?);
        for command in INIT {
            let reply = self.transact(link, command, self.reply_timeout)?;
            proto::parse_ok(&reply, command).map_err(|e| elm_error(command, e))?;
        }
        Ok(())
    }

    fn poll(&mut self, link: &mut dyn Link) -> Result<Reading, DriverError> {
        let m = self.map.clone();
        let mut r = Reading::default();
        if m.rpm.is_some() || m.running.is_some() {
            let rpm = self.read_pid(link, Pid::Rpm)?;
            if let Some(i) = m.rpm {
                r.set(i, rpm);
            }
            if let Some(i) = m.running {
                r.set(i, f64::from(u8::from(rpm > RUNNING_RPM)));
            }
        }
        if let Some(i) = m.speed {
            r.set(i, self.read_pid(link, Pid::Speed)?);
        }
        if let Some(i) = m.coolant {
            if self.polls.is_multiple_of(COOLANT_EVERY) {
                // A car that does not report coolant still reports the rest.
                self.coolant = match self.read_pid(link, Pid::Coolant) {
                    Ok(c) => Some(c),
                    Err(DriverError::Refused(_)) => None,
                    Err(e) => return Err(e),
                };
            }
            if let Some(c) = self.coolant {
                r.set(i, c);
            }
        }
        self.polls += 1;
        Ok(r)
    }

    fn command(&mut self, _link: &mut dyn Link, command: Command) -> Result<(), DriverError> {
        Err(DriverError::Unsupported(format!(
            "the OBD-II adapter is a sensor; it takes no command ({command:?})"
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::driver::mock::{rx, tx, MockLink, Step};

    const T: Duration = Duration::from_millis(300);

    fn full() -> ElmMap {
        ElmMap {
            rpm: Some(0),
            speed: Some(1),
            coolant: Some(2),
            running: Some(3),
        }
    }

    fn init_script() -> Vec<Step> {
        vec![
            tx(b"ATZ\r"),
            rx(b"ATZ\r\r\rELM327 v1.5\r\r>"),
            tx(b"ATE0\r"),
            rx(b"ATE0\rOK\r\r>"),
            tx(b"ATL0\r"),
            rx(b"OK\r\r>"),
            tx(b"ATH0\r"),
            rx(b"OK\r\r>"),
            tx(b"ATSP0\r"),
            rx(b"OK\r\r>"),
        ]
    }

    #[test]
    fn open_resets_and_configures_the_adapter() {
        let mut link = MockLink::new(init_script());
        let mut d = Elm327Driver::new(full(), T);
        d.open(&mut link).unwrap();
        assert_eq!(d.banner(), Some("ELM327 v1.5"));
    }

    #[test]
    fn open_fails_on_a_refused_setting() {
        let mut script = init_script();
        script.truncate(4);
        script.push(tx(b"ATL0\r"));
        script.push(rx(b"?\r\r>"));
        let mut link = MockLink::new(script);
        match Elm327Driver::new(full(), T).open(&mut link) {
            Err(DriverError::Refused(why)) => assert!(why.starts_with("ATL0"), "{why}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn an_adapter_that_is_not_an_elm327_is_garbled() {
        let mut link = MockLink::new([tx(b"ATZ\r"), rx(b"\r\rHELLO\r\r>")]);
        assert!(matches!(
            Elm327Driver::new(full(), T).open(&mut link),
            Err(DriverError::Garbled(_))
        ));
    }

    #[test]
    fn poll_reads_rpm_speed_and_now_and_then_coolant() {
        let mut script = init_script();
        script.extend([
            tx(b"010C\r"),
            rx(b"SEARCHING...\r41 0C 0C 80 \r\r>"),
            tx(b"010D\r"),
            rx(b"41 0D 48 \r\r>"),
            tx(b"0105\r"),
            rx(b"41 05 7B \r\r>"),
        ]);
        for _ in 1..COOLANT_EVERY {
            script.extend([
                tx(b"010C\r"),
                rx(b"41 0C 00 00 \r\r>"),
                tx(b"010D\r"),
                rx(b"41 0D 00 \r\r>"),
            ]);
        }
        script.extend([
            tx(b"010C\r"),
            rx(b"41 0C 00 00 \r\r>"),
            tx(b"010D\r"),
            rx(b"41 0D 00 \r\r>"),
            tx(b"0105\r"),
            rx(b"NO DATA\r\r>"),
        ]);
        let mut link = MockLink::new(script);
        let mut d = Elm327Driver::new(full(), T);
        d.open(&mut link).unwrap();
        let r = d.poll(&mut link).unwrap();
        assert_eq!(r.get(0), Some(800.0), "rpm");
        assert_eq!(r.get(1), Some(20.0), "72 km/h is 20 m/s");
        assert_eq!(r.get(2), Some(83.0), "coolant");
        assert_eq!(r.get(3), Some(1.0), "running");
        for _ in 1..COOLANT_EVERY {
            let r = d.poll(&mut link).unwrap();
            assert_eq!(r.get(2), Some(83.0), "the last coolant value stays");
            assert_eq!(r.get(3), Some(0.0), "not running");
        }
        let r = d.poll(&mut link).unwrap();
        assert_eq!(r.get(2), None, "a coolant PID that went silent is unknown");
    }

    #[test]
    fn the_first_request_waits_for_the_search() {
        let mut link = MockLink::new([
            tx(b"010C\r"),
            rx(b"41 0C 00 00\r\r>"),
            tx(b"010D\r"),
            rx(b"41 0D 00\r\r>"),
        ]);
        let mut d = Elm327Driver::new(full(), T);
        d.read_pid(&mut link, Pid::Rpm).unwrap();
        assert!(link.timeout.is_some_and(|t| t > T && t <= SEARCH_TIMEOUT));
        d.read_pid(&mut link, Pid::Speed).unwrap();
        assert!(link.timeout.is_some_and(|t| t <= T));
    }

    #[test]
    fn no_data_and_silence_fail_the_poll() {
        let mut link = MockLink::new([tx(b"010C\r"), rx(b"NO DATA\r\r>")]);
        match Elm327Driver::new(full(), T).poll(&mut link) {
            Err(DriverError::Refused(why)) => assert_eq!(why, "rpm: NO DATA"),
            other => panic!("{other:?}"),
        }
        let mut link = MockLink::new([tx(b"010C\r"), rx(b"41 0C"), Step::Silence]);
        assert!(matches!(
            Elm327Driver::new(full(), T).poll(&mut link),
            Err(DriverError::Timeout(_))
        ));
    }

    #[test]
    fn commands_are_unsupported() {
        let mut link = MockLink::new([]);
        assert!(matches!(
            Elm327Driver::new(full(), T).command(&mut link, Command::Set(1.0)),
            Err(DriverError::Unsupported(_))
        ));
    }
}
