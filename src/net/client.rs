//! The two network clients: `adrive send`, which sends commands the way a planner
//! would (once, or repeated at a rate with a rolling counter), and `adrive watch`,
//! which prints the state broadcast as it arrives.

use super::auth::Auth;
use super::intake::REPLY_EVERY;
use super::proto::{self, NetCommand, Vocabulary, MAX_DATAGRAM};
use crate::snapshot::{Assembler, Snapshot};
use crate::value::{Keyword, Value};
use socket2::{Domain, Protocol, Socket, Type};
use std::fmt::Write as _;
use std::io::{self, Write};
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// How long a one-shot `send` waits for a reply that may not come (an accepted command
/// is not answered).
pub(crate) const REPLY_WAIT: Duration = Duration::from_millis(200);
/// How long `send` waits for the reply to `engage`, `disengage`, `release` or `clear`,
/// which adrive always answers unless the datagram was dropped (a sender not on the allow list,
/// `replies = false`, a lost datagram).
pub(crate) const EXPECTED_REPLY_WAIT: Duration = Duration::from_secs(1);

/// `adrive send`'s exit statuses.
pub(crate) mod status {
    /// Sent, and nothing was refused.
    pub(crate) const OK: i32 = 0;
    /// Something was refused, or nothing listens at the address (with `--rate`: at its
    /// end, [`still_refused`], or the last datagram found nothing listening).
    pub(crate) const REFUSED: i32 = 1;
    /// A bad command line.
    pub(crate) const USAGE: i32 = 2;
    /// `engage`, `disengage`, `release` or `clear` got no reply: whether it was applied
    /// is unknown.
    pub(crate) const NO_REPLY: i32 = 3;
}

/// Command-line words to protocol lines: a keyword that takes no value (`engage`,
/// `disengage`, `release`, `clear`: [`Keyword::takes_value`]) stands alone, every
/// other line is a name and a value, so `engage trans drive accel 0.3` and
/// `'trans drive' 'accel 0.3'` both work whatever the vehicle's devices are called.
/// A `;` or newline inside an argument also ends a line.
pub(crate) fn lines_from_words(words: &[String]) -> String {
    let mut lines: Vec<Vec<String>> = Vec::new();
    let alone = |w: &str| Keyword::from_word(w).is_some_and(|k| !k.takes_value());
    for arg in words {
        for (k, part) in arg.split([';', '\n']).enumerate() {
            for (j, w) in part.split_whitespace().enumerate() {
                let split = k > 0 && j == 0;
                match lines.last_mut() {
                    Some(l) if !split && !alone(w) && l.len() == 1 && !alone(&l[0]) => {
                        l.push(w.to_string())
                    }
                    _ => lines.push(vec![w.to_string()]),
                }
            }
        }
    }
    lines.iter().map(|l| format!("{}\n", l.join(" "))).collect()
}

/// What `send` does.
pub(crate) struct SendOptions {
    pub to: SocketAddr,
    /// Repeat at this many datagrams a second until stopped.
    pub rate: Option<f64>,
    /// Stop after this many datagrams.
    pub count: Option<u64>,
    pub auth: Option<Auth>,
}

/// Unix time in nanoseconds: a counter that grows across runs, for signed datagrams.
fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

/// `adrive send`: returns the exit status ([`status`]).
pub(crate) fn send(opts: &SendOptions, body: &str, stop: &AtomicBool) -> io::Result<i32> {
    // The keywords adrive always answers, in words, as sent.
    let answered: Vec<&str> = match proto::parse(body.as_bytes(), &Vocabulary::open()) {
        Ok(d) => d
            .commands
            .iter()
            .filter_map(|c| match c {
                NetCommand::Engage => Some("engage"),
                NetCommand::Disengage => Some("disengage"),
                NetCommand::Release => Some("release"),
                NetCommand::Clear => Some("clear"),
                _ => None,
            })
            .collect(),
        Err(e) => {
            eprintln!("adrive send: {e}");
            eprintln!("the commands, one per line, as sent:\n{body}");
            return Ok(status::USAGE);
        }
    };
    let expects_reply = !answered.is_empty();
    let no_reply = || {
        eprintln!(
            "adrive send: no reply from {} within {}: the {} may not have been applied \
             (this sender not on its allow list, `replies = false`, or the datagram lost); \
             `adrive watch` shows the vehicle's state",
            opts.to,
            humantime::format_duration(EXPECTED_REPLY_WAIT),
            answered.join(" and ")
        );
    };
    let any: SocketAddr = if opts.to.is_ipv6() {
        (Ipv6Addr::UNSPECIFIED, 0).into()
    } else {
        (Ipv4Addr::UNSPECIFIED, 0).into()
    };
    let socket = UdpSocket::bind(any)?;
    socket.connect(opts.to)?;
    let mut seq: u64 = 0;
    let mut datagram = |repeat: bool| -> String {
        seq = match (&opts.auth, repeat) {
            (Some(_), _) => now_ns().max(seq + 1),
            (None, true) => seq + 1,
            (None, false) => 0,
        };
        match &opts.auth {
            Some(a) => a.sign(body, seq),
            None if repeat => format!("seq {seq}\n{body}"),
            None => body.to_string(),
        }
    };
    let mut buf = [0u8; 2048];
    let Some(rate) = opts.rate else {
        let text = datagram(false);
        check_size(&text)?;
        socket.send(text.as_bytes())?;
        socket.set_read_timeout(Some(if expects_reply {
            EXPECTED_REPLY_WAIT
        } else {
            REPLY_WAIT
        }))?;
        return match socket.recv(&mut buf) {
            Ok(n) => {
                let reply = String::from_utf8_lossy(&buf[..n]);
                // The status tells the outcome, read or not (`| head`).
                let _ = io::stdout().write_all(reply.as_bytes());
                Ok(if refused(&reply) {
                    status::REFUSED
                } else {
                    status::OK
                })
            }
            Err(e) if e.kind() == io::ErrorKind::ConnectionRefused => {
                eprintln!("adrive send: nothing is listening at {}", opts.to);
                Ok(status::REFUSED)
            }
            Err(_) if expects_reply => {
                no_reply();
                Ok(status::NO_REPLY)
            }
            Err(_) => Ok(status::OK),
        };
    };
    if !(rate.is_finite() && rate > 0.0 && rate <= 10_000.0) {
        eprintln!("adrive send: --rate takes datagrams per second, above 0 and at most 10000");
        return Ok(status::USAGE);
    }
    let period = Duration::from_secs_f64(1.0 / rate);
    #[allow(unsafe_code)]
    // Wake within a microsecond of when asked, not the default 50 µs later: at
    // 10,000 a second that is half a period.
    // SAFETY: PR_SET_TIMERSLACK takes a number of nanoseconds and touches nothing else.
    unsafe {
        libc::prctl(libc::PR_SET_TIMERSLACK, 1000)
    };
    socket.set_nonblocking(true)?;
    let start = Instant::now();
    let mut next = start;
    let mut sent = 0u64;
    let mut last_reply = String::new();
    let mut unreachable = false;
    // The datagram sent last found nothing listening (an ICMP port unreachable, read
    // back as ECONNREFUSED within its period): the status at the end.
    let mut refused_last = false;
    // An expected reply: got one yet, and said that it is overdue.
    let (mut replied, mut warned) = (false, false);
    // Replies that refused something, when the last came, and whether the last reply's
    // text refuses (a reply the same as the last is not read again).
    let (mut refusals, mut refused_at, mut reply_refuses) = (0u64, None, false);
    eprintln!(
        "adrive send: {} a second to {}; Ctrl-C stops (the watchdog then stops the vehicle)",
        rate, opts.to
    );
    while !stop.load(Relaxed) && opts.count.is_none_or(|c| sent < c) {
        let text = datagram(true);
        check_size(&text)?;
        match socket.send(text.as_bytes()) {
            Ok(_) => {
                sent += 1;
                refused_last = false;
            }
            // The refusal of an earlier datagram, reported instead of sending this one.
            Err(e) if e.kind() == io::ErrorKind::ConnectionRefused => refused_last = true,
            Err(e) => return Err(e),
        }
        next += period;
        // Read replies until the next datagram is due. The wait is a poll with a
        // nanosecond timeout: a socket read timeout is rounded up to the kernel's tick
        // (4 ms at 250 Hz), which held every rate to about 250 a second.
        loop {
            let left = next.saturating_duration_since(Instant::now());
            if left.is_zero() || stop.load(Relaxed) {
                break;
            }
            if !readable(&socket, left)? {
                continue;
            }
            match socket.recv(&mut buf) {
                Ok(n) => {
                    if unreachable {
                        eprintln!("adrive send: {} replies again", opts.to);
                    }
                    unreachable = false;
                    refused_last = false;
                    replied = true;
                    let reply = String::from_utf8_lossy(&buf[..n]).into_owned();
                    if reply != last_reply {
                        reply_refuses = refused(&reply);
                        // Sending is the job: an output nobody reads (`| head`) is no
                        // reason to stop commanding the vehicle.
                        let mut out = io::stdout().lock();
                        for line in reply.lines() {
                            let at = start.elapsed().as_secs_f64();
                            let _ = writeln!(out, "{at:>8.3}s {line}");
                        }
                        let _ = out.flush();
                        last_reply = reply;
                    }
                    if reply_refuses {
                        refusals += 1;
                        refused_at = Some(Instant::now());
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::ConnectionRefused => {
                    refused_last = true;
                    if !unreachable {
                        // What is known: its port refuses now; and whether it replied
                        // before (then it stopped, or moved), or never did.
                        let when = if replied {
                            "any more (it replied before)"
                        } else {
                            "(yet)"
                        };
                        eprintln!("adrive send: nothing is listening at {} {when}", opts.to);
                        unreachable = true;
                    }
                    std::thread::sleep(left.min(Duration::from_millis(5)));
                }
                Err(_) => {}
            }
        }
        // Nothing listening has been said already.
        if expects_reply
            && !replied
            && !warned
            && !unreachable
            && start.elapsed() >= EXPECTED_REPLY_WAIT
        {
            no_reply();
            warned = true;
        }
        // A late wake (a loaded machine) is made up, within CATCH_UP: at high rates
        // the asked rate holds; a planner at 20 Hz never sends a burst.
        next = next.max(Instant::now() - period.max(CATCH_UP));
    }
    let refused_at_end = refused_at.is_some_and(|t| t.elapsed() <= still_refused(period));
    eprintln!(
        "adrive send: sent {sent} datagrams in {:.1} s{}{}",
        start.elapsed().as_secs_f64(),
        match refusals {
            0 => String::new(),
            1 => "; a reply refused something".into(),
            n => format!("; {n} replies refused something"),
        },
        if refused_last {
            format!("; nothing is listening at {}", opts.to)
        } else {
            String::new()
        }
    );
    // As for one datagram, at its end: something refused, or nothing listening, is
    // status 1, before a missing reply (nothing could have answered).
    Ok(if refused_last || refused_at_end {
        status::REFUSED
    } else if expects_reply && !replied {
        status::NO_REPLY
    } else {
        status::OK
    })
}

/// How recent a refusal must be, at the end of a stream sent every `period`, for the
/// stream to have ended refused: its last three periods, and 60 ms at least. adrive
/// answers an accepted command with nothing and a sender at most every
/// [`REPLY_EVERY`]: a stream refused to its end has had a refusal within two of the
/// longer of the two (a third for a late reply), and one that outlived its refusals
/// (an `accel` while the gearbox shifts) has had none since.
fn still_refused(period: Duration) -> Duration {
    3 * period.max(REPLY_EVERY)
}

/// How far behind its schedule `send --rate` may fall before it gives up making up
/// the datagrams it owes (it sends them back to back until then).
const CATCH_UP: Duration = Duration::from_millis(2);

/// Wait at most `timeout` for `socket` to have something to read.
fn readable(socket: &UdpSocket, timeout: Duration) -> io::Result<bool> {
    use rustix::event::{PollFd, PollFlags, Timespec};
    let mut fds = [PollFd::new(socket, PollFlags::IN)];
    let timeout = Timespec::try_from(timeout).map_err(io::Error::other)?;
    match rustix::event::poll(&mut fds, Some(&timeout)) {
        Ok(n) => Ok(n > 0),
        Err(rustix::io::Errno::INTR) => Ok(false),
        Err(e) => Err(e.into()),
    }
}

fn check_size(text: &str) -> io::Result<()> {
    if text.len() > MAX_DATAGRAM {
        return Err(io::Error::other(format!(
            "the datagram would be {} bytes; adrive takes at most {MAX_DATAGRAM}",
            text.len()
        )));
    }
    Ok(())
}

/// Does a reply refuse or reject anything?
pub(crate) fn refused(reply: &str) -> bool {
    reply
        .lines()
        .any(|l| l.starts_with("refused") || l.starts_with("rejected"))
}

/// A socket that receives the state broadcast sent to `from` (a unicast address of
/// this host, or a multicast group, joined on every interface).
pub(crate) fn watch_socket(from: SocketAddr) -> io::Result<UdpSocket> {
    let s = Socket::new(Domain::for_address(from), Type::DGRAM, Some(Protocol::UDP))?;
    // Several watchers of one multicast group on one host.
    s.set_reuse_address(true)?;
    let bind: SocketAddr = match from.ip() {
        IpAddr::V4(g) if g.is_multicast() => {
            s.bind(&SocketAddr::from((Ipv4Addr::UNSPECIFIED, from.port())).into())?;
            s.join_multicast_v4(&g, &Ipv4Addr::UNSPECIFIED)?;
            return Ok(s.into());
        }
        IpAddr::V6(g) if g.is_multicast() => {
            s.bind(&SocketAddr::from((Ipv6Addr::UNSPECIFIED, from.port())).into())?;
            s.join_multicast_v6(&g, 0)?;
            return Ok(s.into());
        }
        _ => from,
    };
    s.bind(&bind.into())?;
    Ok(s.into())
}

/// `adrive watch`: print each broadcast until stopped (or `count` of them).
pub(crate) fn watch(
    from: SocketAddr,
    json: bool,
    count: Option<u64>,
    stop: &AtomicBool,
) -> io::Result<i32> {
    let socket = watch_socket(from).map_err(|e| {
        let why = crate::config::network::bind_error(
            "--from",
            from,
            "--from is where the broadcast is sent to (the watched adrive's [network] \
             broadcast_to or --broadcast-to): an address of this host or a multicast group; \
             to watch an adrive on another host, have it broadcast to this one",
            &e,
        );
        io::Error::new(e.kind(), why)
    })?;
    socket.set_read_timeout(Some(Duration::from_millis(200)))?;
    if !json {
        eprintln!(
            "adrive watch: listening on {from}; each device as commanded/measured; Ctrl-C stops"
        );
    }
    let mut buf = vec![0u8; 65536];
    let mut seen = 0u64;
    let mut parts = Assembler::default();
    let mut last_gate = String::new();
    let mut out = io::stdout().lock();
    while !stop.load(Relaxed) && count.is_none_or(|c| seen < c) {
        let n = match socket.recv(&mut buf) {
            Ok(n) => n,
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                continue
            }
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        let bytes = &buf[..n];
        let snap = match serde_json::from_slice::<Snapshot>(bytes) {
            Ok(v) => v,
            Err(e) => {
                if !json {
                    writeln!(out, "?? not a state broadcast ({e}): {n} bytes")?;
                    out.flush()?;
                }
                continue;
            }
        };
        let whole_datagram = snap.part.is_none();
        // A vehicle of many devices broadcasts in parts: one line per whole snapshot.
        let Some(v) = parts.push(snap) else {
            continue;
        };
        seen += 1;
        if json {
            if whole_datagram {
                out.write_all(bytes)?;
            } else {
                serde_json::to_writer(&mut out, &v)?;
            }
            out.write_all(b"\n")?;
        } else {
            if v.gate.reason != last_gate {
                writeln!(out, "-- {}", v.gate.reason)?;
                last_gate = v.gate.reason.clone();
            }
            writeln!(out, "{}", human_line(&v))?;
        }
        out.flush()?;
    }
    Ok(0)
}

fn value(v: Option<&Value>) -> String {
    match v {
        Some(Value::Number(n)) => format!("{n:.2}"),
        Some(other) => other.to_string(),
        None => "-".into(),
    }
}

/// One snapshot as one line for a person: each actuator as commanded/measured, each
/// sensor's readings.
pub(crate) fn human_line(v: &Snapshot) -> String {
    let mut l = String::new();
    let _ = write!(
        l,
        "{:>7.1}s {:<10} watchdog {:<7}",
        v.uptime_s,
        if v.gate.engaged {
            "ENGAGED"
        } else {
            "disengaged"
        },
        v.gate
            .watchdog
            .as_ref()
            .map_or("-".to_string(), |w| format!("{:?}", w.state).to_lowercase()),
    );
    for d in &v.devices {
        let flag = if d.health.faulty { "!FAULTY" } else { "" };
        if d.is_actuator() {
            let measured = d.readings.0.first().and_then(|(_, v)| v.as_ref());
            let _ = write!(
                l,
                " | {} {}/{}{flag}",
                d.name,
                value(d.commanded.as_ref()),
                value(measured)
            );
        } else {
            let _ = write!(l, " | {}", d.name);
            let single = d.readings.len() == 1;
            for ((name, v), (_, units)) in d.readings.iter().zip(d.reading_units.iter()) {
                // `estop run`, `obd rpm=700.00 speed=0.00m/s …`
                if single {
                    let _ = write!(l, " {}", value(v.as_ref()));
                } else {
                    let _ = write!(l, " {name}={}", value(v.as_ref()));
                }
                if !units.is_empty() && units != name && matches!(v, Some(Value::Number(_))) {
                    let sep = if units.starts_with(char::is_alphabetic) && single {
                        " "
                    } else {
                        ""
                    };
                    let _ = write!(l, "{sep}{units}");
                }
            }
            l.push_str(flag);
        }
    }
    l
}

#[cfg(test)]
mod tests {
    use super::*;

    fn words(s: &[&str]) -> String {
        lines_from_words(&s.iter().map(|w| w.to_string()).collect::<Vec<_>>())
    }

    #[test]
    fn words_become_one_line_per_command() {
        assert_eq!(
            words(&["engage", "trans", "drive", "accel", "0.3"]),
            "engage\ntrans drive\naccel 0.3\n"
        );
        assert_eq!(
            words(&["signal", "left", "horn", "on", "disengage"]),
            "signal left\nhorn on\ndisengage\n"
        );
        assert_eq!(words(&["steer 0.2", "GAS", "0"]), "steer 0.2\nGAS 0\n");
        assert_eq!(words(&["steer 0.2; brake 1"]), "steer 0.2\nbrake 1\n");
        assert_eq!(words(&["steer", "-0.25"]), "steer -0.25\n");
        assert_eq!(
            words(&["release", "clear", "engage"]),
            "release\nclear\nengage\n"
        );
    }

    /// `adrive watch`: each actuator as commanded/measured, each sensor's readings
    /// with their units.
    #[test]
    fn a_broadcast_is_one_line_for_a_person() {
        let snap = crate::testkit::gate(Instant::now()).snapshot(0);
        let l = human_line(&snap);
        assert!(l.contains("disengaged watchdog off"), "{l}");
        assert!(
            l.contains(" | steer -/0.23 | gas -/0.00 | brake -/1.00 | trans -/park"),
            "{l}"
        );
        assert!(
            l.ends_with(" | estop run | obd rpm=700.00 speed=0.00m/s coolant=85.00°C running=yes"),
            "{l}"
        );
    }

    #[test]
    fn a_reply_that_refuses_is_noticed() {
        assert!(refused(
            "ok engaged\nrejected gas 0.3: gas_while_braking: …\n"
        ));
        assert!(!refused("ok engaged\n"));
    }
}
