//! The network side of the engine, the paper's two network threads plus what today's
//! drive-by-wire interfaces add:
//!
//! - `net/listen` owns the UDP command socket. Each datagram is stamped the moment
//!   the kernel hands it over (under a flood, reads are paced: [`pace`]), then [`intake`] checks the sender (allow-list), the grammar
//!   ([`proto`]), the key ([`auth`]) and the rolling counter, and hands each command,
//!   tagged with its sender, to the one intake ([`Gate::admit`]), which decides who
//!   commands, feeds the commander's watchdog, checks the interlocks, stores it in the
//!   device's slot and wakes its command thread.
//! - `net/broadcast` sends the [`Snapshot`] as one JSON
//!   object per datagram at `broadcast_rate`, to unicast addresses and/or multicast
//!   groups.
//!
//! The watchdog of a commanding sender is the intake's ([`Gate::watch`]): quiet, or
//! with its rolling counter stopped, for `watchdog_timeout`, it brings the vehicle to
//! the safe state and disengages it. [`NetStatus`] publishes counters and senders for the console and the
//! broadcast; [`client`] holds `adrive send` and `adrive watch`.

pub mod auth;
pub(crate) mod client;

pub(crate) mod counters;
#[doc(hidden)]
pub mod fuzzing;
pub mod intake;
pub(crate) mod pace;
pub mod proto;

pub use crate::config::NetworkConfig;
pub use counters::{NetRefusal, NetStatus};
pub use pace::FLOOD_GAP;

use crate::engine::Gate;
use crate::logging::Repeats;
use crate::snapshot::Snapshot;
use crate::threads::{Group, StopSignal};
use auth::Auth;
use intake::Intake;
use socket2::{Domain, Protocol, Socket, Type};
use std::io;
use std::net::{Ipv4Addr, Ipv6Addr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How often the listener looks up from its socket to check for a stop.
const LISTEN_POLL: Duration = Duration::from_millis(50);
/// Kernel receive buffer asked for the command socket, so a burst waits in the kernel
/// rather than being dropped.
const RECV_BUFFER: usize = 1 << 20;

/// The running network threads.
pub struct Net {
    status: Arc<NetStatus>,
    closing: Arc<AtomicBool>,
    threads: Group,
}

impl Net {
    /// Bind the command socket and start `net/listen`, `net/broadcast` and
    /// `net/watchdog`. A bind error comes back before any thread starts.
    pub fn start(gate: Arc<Gate>, config: NetworkConfig, auth: Option<Auth>) -> io::Result<Net> {
        let socket = bind_command_socket(config.listen).map_err(|e| {
            let why = crate::config::network::bind_error(
                "listen on",
                config.listen,
                "--listen (or [network] listen) is where this adrive takes commands: an \
                     address of this host (127.0.0.1, or 0.0.0.0 for every interface)",
                &e,
            );
            io::Error::new(e.kind(), why)
        })?;
        let local = socket.local_addr()?;
        let out = broadcast_socket(&config)?;
        let status = Arc::new(NetStatus::of(
            gate.vehicle(),
            local,
            config.watchdog_timeout,
        ));
        let closing = Arc::new(AtomicBool::new(false));
        let mut threads = Group::default();

        let mut intake = Intake::new(
            gate.clone(),
            config.clone(),
            auth.clone(),
            status.clone(),
            closing.clone(),
        );
        crate::probe::init();
        let placement = gate.vehicle().config().vehicle.placement.clone();
        threads.spawn("net/listen", move |stop| {
            crate::engine::placement::apply(&placement);
            listen_loop(&socket, &mut intake, stop)
        })?;

        let (g, st) = (gate.clone(), status.clone());
        let (dest, period) = (config.broadcast_to.clone(), config.broadcast_period());
        threads.spawn("net/broadcast", move |stop| {
            broadcast_loop(&out, &dest, period, &g, &st, stop)
        })?;

        tracing::info!(
            listen = %local,
            broadcast = ?config.broadcast_to,
            allow_engage = config.allow_engage,
            key = auth.is_some(),
            watchdog = ?config.watchdog_timeout,
            "network up"
        );
        Ok(Net {
            status,
            closing,
            threads,
        })
    }

    /// Where the command listener is bound (the real port when 0 was asked for).
    pub fn local_addr(&self) -> SocketAddr {
        self.status.listen
    }

    pub fn status(&self) -> &Arc<NetStatus> {
        &self.status
    }

    pub fn thread_names(&self) -> Vec<&str> {
        self.threads.names()
    }

    /// Refuse every datagram from now on (the first step of shutting down).
    pub fn close(&self) {
        self.closing.store(true, Relaxed);
    }
}

impl Drop for Net {
    /// Dropped without being shut down ([`crate::threads::Shutdown`]): datagrams
    /// refused; the threads are told to stop (by their [`Group`]), not joined.
    fn drop(&mut self) {
        self.close();
    }
}

impl crate::threads::Shutdown for Net {
    /// Stop and join the threads; returns the names of those that did not stop.
    fn shutdown(mut self, deadline: Duration) -> Vec<String> {
        self.close();
        self.threads.stop(Instant::now() + deadline)
    }
}

fn bind_command_socket(addr: SocketAddr) -> io::Result<UdpSocket> {
    let s = Socket::new(Domain::for_address(addr), Type::DGRAM, Some(Protocol::UDP))?;
    let _ = s.set_recv_buffer_size(RECV_BUFFER);
    s.bind(&addr.into())?;
    s.set_read_timeout(Some(LISTEN_POLL))?;
    Ok(s.into())
}

/// The socket the state broadcast goes out of (multicast settings from `config`).
pub(crate) fn broadcast_socket(config: &NetworkConfig) -> io::Result<UdpSocket> {
    let v6 = config.broadcast_to.first().is_some_and(SocketAddr::is_ipv6);
    let any: SocketAddr = if v6 {
        (Ipv6Addr::UNSPECIFIED, 0).into()
    } else {
        (Ipv4Addr::UNSPECIFIED, 0).into()
    };
    let s = UdpSocket::bind(any)?;
    if v6 {
        s.set_multicast_loop_v6(true)?;
    } else {
        s.set_multicast_ttl_v4(config.multicast_ttl)?;
        s.set_multicast_loop_v4(true)?;
    }
    Ok(s)
}

/// Datagrams taken from the kernel in one system call at most.
const BATCH: usize = 32;

/// Buffers for one `recvmmsg`: room for [`BATCH`] datagrams and their senders.
struct Batch {
    // One byte more than the largest datagram, so a larger one shows as oversized.
    bufs: [[u8; proto::MAX_DATAGRAM + 1]; BATCH],
    addrs: [libc::sockaddr_storage; BATCH],
    lens: [usize; BATCH],
}

impl Batch {
    #[allow(unsafe_code)]
    fn new() -> Box<Batch> {
        // SAFETY: all-zero bytes are valid for every field (plain bytes and integers).
        unsafe { Box::new(std::mem::zeroed()) }
    }

    /// Wait for at least one datagram (at most the socket's read timeout; not at all
    /// when `wait` is false), then take every one already queued, up to [`BATCH`]:
    /// under a flood, one system call and one wake serve many. Returns how many arrived.
    fn receive(&mut self, socket: &UdpSocket, wait: bool) -> io::Result<usize> {
        use std::os::fd::AsRawFd;
        let mut iov: [libc::iovec; BATCH] = std::array::from_fn(|i| libc::iovec {
            iov_base: self.bufs[i].as_mut_ptr().cast(),
            iov_len: self.bufs[i].len(),
        });
        #[allow(unsafe_code)]
        // SAFETY: an all-zero mmsghdr is a valid empty header; the pointers set below
        // stay valid for the call (they point into `self` and `iov`).
        let mut msgs: [libc::mmsghdr; BATCH] = unsafe { std::mem::zeroed() };
        for (i, m) in msgs.iter_mut().enumerate() {
            m.msg_hdr.msg_name = (&mut self.addrs[i] as *mut libc::sockaddr_storage).cast();
            m.msg_hdr.msg_namelen = std::mem::size_of::<libc::sockaddr_storage>() as u32;
            m.msg_hdr.msg_iov = &mut iov[i];
            m.msg_hdr.msg_iovlen = 1;
        }
        #[allow(unsafe_code)]
        // SAFETY: `msgs` holds BATCH valid headers; the kernel writes within them.
        let n = unsafe {
            libc::recvmmsg(
                socket.as_raw_fd(),
                msgs.as_mut_ptr(),
                BATCH as u32,
                if wait {
                    libc::MSG_WAITFORONE
                } else {
                    libc::MSG_DONTWAIT
                },
                std::ptr::null_mut(),
            )
        };
        if n < 0 {
            return Err(io::Error::last_os_error());
        }
        let n = n as usize;
        for (i, m) in msgs.iter().enumerate().take(n) {
            // A datagram longer than the buffer is cut to it (and so shows as oversized).
            self.lens[i] = (m.msg_len as usize).min(self.bufs[i].len());
        }
        Ok(n)
    }

    /// The `i`th datagram and its sender.
    fn get(&self, i: usize) -> Option<(&[u8], SocketAddr)> {
        Some((&self.bufs[i][..self.lens[i]], sender(&self.addrs[i])?))
    }
}

/// The address the kernel wrote for a datagram's sender.
fn sender(a: &libc::sockaddr_storage) -> Option<SocketAddr> {
    match i32::from(a.ss_family) {
        libc::AF_INET => {
            #[allow(unsafe_code)]
            // SAFETY: the family says the storage holds a sockaddr_in.
            let v4 = unsafe { &*(a as *const libc::sockaddr_storage).cast::<libc::sockaddr_in>() };
            let ip = Ipv4Addr::from(u32::from_be(v4.sin_addr.s_addr));
            Some(SocketAddr::from((ip, u16::from_be(v4.sin_port))))
        }
        libc::AF_INET6 => {
            #[allow(unsafe_code)]
            // SAFETY: the family says the storage holds a sockaddr_in6.
            let v6 = unsafe { &*(a as *const libc::sockaddr_storage).cast::<libc::sockaddr_in6>() };
            let ip = Ipv6Addr::from(v6.sin6_addr.s6_addr);
            Some(SocketAddr::V6(std::net::SocketAddrV6::new(
                ip,
                u16::from_be(v6.sin6_port),
                v6.sin6_flowinfo,
                v6.sin6_scope_id,
            )))
        }
        _ => None,
    }
}

fn listen_loop(socket: &UdpSocket, intake: &mut Intake, stop: &StopSignal) {
    let mut batch = Batch::new();
    let mut errors = Repeats::default();
    let status = intake.status().clone();
    let mut pace = pace::Pace::new(Instant::now(), &status);
    let mut last_read = Instant::now();
    let mut not_before = None;
    while !stop.is_stopped() {
        // Under a flood, pause, then take what queued meanwhile without waiting: those
        // datagrams arrived after the previous read returned, so they are stamped then.
        // Otherwise (and when nothing queued) wait, and stamp when the kernel hands
        // the datagrams over.
        let mut queued = None;
        if let Some(at) = not_before.take() {
            stop.sleep_until(at);
            queued = match batch.receive(socket, false) {
                Ok(0) => None,
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => None,
                other => Some((other, last_read)),
            };
        }
        let (result, received) =
            queued.unwrap_or_else(|| (batch.receive(socket, true), Instant::now()));
        match result {
            Ok(n) => {
                last_read = Instant::now();
                for i in 0..n {
                    let Some((bytes, from)) = batch.get(i) else {
                        continue;
                    };
                    crate::probe::datagram(received);
                    if let Some(reply) = intake.handle(bytes, from, received) {
                        let _ = socket.send_to(reply.as_bytes(), from);
                    }
                    crate::probe::stamp(crate::probe::Step::Handled);
                }
                // A full batch leaves more queued: read on at once, never fall behind.
                not_before = pace.read(last_read, &status).filter(|_| n < BATCH);
            }
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) => {}
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => {
                // E.g. ICMP port unreachable after a reply: log, never spin.
                if let Some(repeats) = errors.note(&e.to_string(), Instant::now()) {
                    tracing::warn!("command socket: {e}{repeats}");
                }
                std::thread::sleep(Duration::from_millis(1));
            }
        }
    }
}

/// The network sender commanding the vehicle, if one does.
pub fn commanding(gate: &Gate) -> Option<SocketAddr> {
    match gate.commander() {
        Some(crate::value::Source::Network(a)) => Some(a),
        _ => None,
    }
}

/// The whole snapshot, the network's part included.
pub fn snapshot(gate: &Gate, status: &NetStatus, seq: u64) -> Snapshot {
    let mut snap = gate.snapshot(seq);
    snap.net = Some(status.snapshot(gate));
    snap
}

/// The largest state broadcast datagram: a snapshot larger than this (a vehicle of
/// many devices) goes out in parts ([`Snapshot::datagrams`]) that `adrive watch`
/// joins. Alice's snapshot fits in one.
pub(crate) const BROADCAST_MAX: usize = 16 * 1024;

fn broadcast_loop(
    socket: &UdpSocket,
    dest: &[SocketAddr],
    period: Duration,
    gate: &Gate,
    status: &NetStatus,
    stop: &StopSignal,
) {
    // One condition per destination: each fails or recovers on its own.
    let mut errors: Vec<Repeats> = dest.iter().map(|_| Repeats::default()).collect();
    let mut seq = 0u64;
    crate::threads::every(period, stop, || {
        let snap = snapshot(gate, status, seq);
        seq += 1;
        let datagrams = match snap.datagrams(BROADCAST_MAX) {
            Ok(d) => d,
            Err(e) => {
                tracing::error!("state broadcast: {e}");
                return;
            }
        };
        // A recording keeps the snapshot whole, however many parts it went out in.
        gate.vehicle()
            .tap()
            .send(|| crate::vehicle::tap::Event::Snapshot {
                at: Instant::now(),
                json: match datagrams.as_slice() {
                    [whole] => whole.clone(),
                    _ => serde_json::to_vec(&snap).unwrap_or_default(),
                },
            });
        for (to, errors) in dest.iter().zip(&mut errors) {
            for bytes in &datagrams {
                match socket.send_to(bytes, to) {
                    Ok(_) => errors.clear(),
                    Err(e) => {
                        let what = format!("state broadcast to {to}: {e}");
                        if let Some(repeats) = errors.note(&what, Instant::now()) {
                            tracing::warn!("{what}{repeats}");
                        }
                    }
                }
            }
        }
    });
}
