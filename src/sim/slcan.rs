//! A simulated SLCAN adapter (a CANable, a Lawicel CANUSB) with a CAN bus behind it:
//! the adapter's state machine on bytes and frames alone, and [`SlcanPort`], the adapter
//! joined to the nodes on its bus ([`BusNode`], e.g. the OSCC kit of [`super::oscc`]).
//!
//! It behaves as the Lawicel documentation says a strict adapter does, so that a host
//! that skips a step finds out here rather than on the vehicle: the bitrate and
//! timestamps are set only while the channel is closed, `O` needs a bitrate first, a
//! frame is sent only while open (and not listening only), and anything it cannot take
//! is answered with BEL. A sent frame is acknowledged with `z`/`Z`; frames from the bus
//! reach the host only while the channel is open, with a millisecond timestamp when
//! timestamps are on. A bus fault can be injected: the adapter then refuses to send,
//! delivers nothing, and its status flags say why.

use crate::can::Frame;
use crate::driver::slcan::proto::{
    encode_event, Bitrate, Command, Decoder, Event, FromHost, StatusFlags, TIMESTAMP_WRAP,
};
use std::time::{Duration, Instant};

/// What `V` answers: hardware 1.0, software 1.3.
pub const VERSION: [u8; 4] = *b"1013";
/// What `N` answers.
pub const SERIAL: [u8; 4] = *b"AD01";

/// The adapter's state.
#[derive(Debug)]
pub struct Adapter {
    bitrate: Option<Bitrate>,
    open: bool,
    listen_only: bool,
    timestamps: bool,
    /// Flags gathered since the host last read them with `F`.
    flags: StatusFlags,
    /// The bus is in error (injected): nothing is sent or delivered.
    bus_fault: bool,
    /// Where timestamps count from.
    epoch: Instant,
    decoder: Decoder<FromHost>,
}

impl Adapter {
    /// An adapter just plugged in: closed, no bitrate, timestamps off.
    pub fn new(now: Instant) -> Adapter {
        Adapter {
            bitrate: None,
            open: false,
            listen_only: false,
            timestamps: false,
            flags: StatusFlags::default(),
            bus_fault: false,
            epoch: now,
            decoder: Decoder::new(),
        }
    }

    pub fn is_open(&self) -> bool {
        self.open
    }

    pub fn bitrate(&self) -> Option<Bitrate> {
        self.bitrate
    }

    /// Put the bus in error (bus-off, a missing terminator) or take it out: while in
    /// error the adapter refuses frames, delivers none, and `F` reports a bus error.
    pub fn set_bus_fault(&mut self, on: bool) {
        self.bus_fault = on;
        if on {
            self.flags.0 |= StatusFlags::BUS_ERROR | StatusFlags::ERROR_PASSIVE;
        }
    }

    /// One command from the host: the answer goes to `reply`, a frame to send onto the
    /// bus is returned.
    pub fn command(&mut self, command: Command, reply: &mut Vec<u8>) -> Option<Frame> {
        let mut sent = None;
        let event = match command {
            Command::Open | Command::ListenOnly if self.open || self.bitrate.is_none() => {
                Event::Refused
            }
            Command::Open | Command::ListenOnly => {
                self.open = true;
                self.listen_only = command == Command::ListenOnly;
                Event::Ok
            }
            Command::Close => {
                self.open = false;
                Event::Ok
            }
            Command::Bitrate(_) | Command::Timestamps(_) if self.open => Event::Refused,
            Command::Bitrate(b) => {
                self.bitrate = Some(b);
                Event::Ok
            }
            Command::Timestamps(on) => {
                self.timestamps = on;
                Event::Ok
            }
            Command::Status if !self.open => Event::Refused,
            Command::Status => {
                let flags = self.flags;
                self.flags = StatusFlags(if self.bus_fault {
                    StatusFlags::BUS_ERROR | StatusFlags::ERROR_PASSIVE
                } else {
                    0
                });
                Event::Status(flags)
            }
            Command::Version => Event::Version(VERSION),
            Command::Serial => Event::Serial(SERIAL),
            Command::Transmit(_) if !self.open || self.listen_only || self.bus_fault => {
                Event::Refused
            }
            Command::Transmit(frame) => {
                sent = Some(frame);
                Event::Sent {
                    extended: frame.id().is_extended(),
                }
            }
            Command::Nothing => Event::Ok,
        };
        reply.extend_from_slice(&encode_event(&event));
        sent
    }

    /// Bytes from the host as they arrive: every whole command is carried out, its
    /// answer appended to `reply` and the frames it sends appended to `bus`.
    pub fn receive(&mut self, bytes: &[u8], reply: &mut Vec<u8>, bus: &mut Vec<Frame>) {
        self.decoder.push(bytes);
        while let Some(item) = self.decoder.next() {
            match item {
                Ok(command) => bus.extend(self.command(command, reply)),
                Err(_) => reply.extend_from_slice(&encode_event(&Event::Refused)),
            }
        }
    }

    /// A frame from the bus at `now`: its line goes to the host if the channel is open
    /// and the bus is well.
    pub fn deliver(&mut self, frame: &Frame, now: Instant, to_host: &mut Vec<u8>) {
        if !self.open || self.bus_fault {
            return;
        }
        let timestamp = self.timestamps.then(|| {
            (now.saturating_duration_since(self.epoch).as_millis() % TIMESTAMP_WRAP as u128) as u16
        });
        to_host.extend_from_slice(&encode_event(&Event::Received {
            frame: *frame,
            timestamp,
        }));
    }
}

/// A node on the simulated bus behind the adapter (a kit's modules, the vehicle's own
/// ECUs).
pub trait BusNode: Send {
    /// A frame someone put on the bus at `now`.
    fn receive(&mut self, frame: &Frame, now: Instant);
    /// Whatever the node does by itself up to `now` (reports at their rate, a watchdog
    /// tripping): frames it sends go to `bus`.
    fn tick(&mut self, now: Instant, bus: &mut Vec<Frame>);
    /// When the node next has something to do.
    fn next_due(&self) -> Instant;
}

/// An adapter and the bus behind it: what the simulator's port loop drives with the
/// bytes of its pseudo-terminal and the clock.
pub struct SlcanPort<N> {
    pub adapter: Adapter,
    pub node: N,
    bus: Vec<Frame>,
}

impl<N: BusNode> SlcanPort<N> {
    pub fn new(node: N, now: Instant) -> SlcanPort<N> {
        SlcanPort {
            adapter: Adapter::new(now),
            node,
            bus: Vec::new(),
        }
    }

    /// Bytes from the host at `now`; what goes back to the host is appended to
    /// `to_host` (the answers, in order). Returns the frames the host put on the bus.
    pub fn input(&mut self, bytes: &[u8], now: Instant, to_host: &mut Vec<u8>) -> &[Frame] {
        self.bus.clear();
        self.adapter.receive(bytes, to_host, &mut self.bus);
        for frame in &self.bus {
            self.node.receive(frame, now);
        }
        &self.bus
    }

    /// Let the bus run to `now`: the frames its nodes send reach the host through the
    /// adapter.
    pub fn tick(&mut self, now: Instant, to_host: &mut Vec<u8>) {
        self.poll(now);
        for frame in &self.bus {
            self.adapter.deliver(frame, now, to_host);
        }
    }

    /// Let the bus's nodes run to `now` and return the frames they send, for a port
    /// loop that hands each to the host ([`Adapter::deliver`]) once its wire time has
    /// passed; [`SlcanPort::tick`] hands them over at once.
    pub fn poll(&mut self, now: Instant) -> &[Frame] {
        self.bus.clear();
        self.node.tick(now, &mut self.bus);
        &self.bus
    }

    /// How long the port loop may wait for input before [`SlcanPort::tick`] is due.
    pub fn wait(&self, now: Instant) -> Duration {
        self.node.next_due().saturating_duration_since(now)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::can::Id;
    use crate::driver::slcan::proto::{bring_up, encode_command, FromAdapter};

    fn events(bytes: &[u8]) -> Vec<Event> {
        let mut d = Decoder::<FromAdapter>::new();
        d.push(bytes);
        std::iter::from_fn(|| d.next()).collect()
    }

    fn send(a: &mut Adapter, text: &[u8]) -> (Vec<Event>, Vec<Frame>) {
        let mut reply = Vec::new();
        let mut bus = Vec::new();
        a.receive(text, &mut reply, &mut bus);
        (events(&reply), bus)
    }

    #[test]
    fn a_host_must_set_the_bitrate_before_opening_and_may_not_change_it_while_open() {
        let mut a = Adapter::new(Instant::now());
        assert_eq!(
            send(&mut a, b"O\r").0,
            vec![Event::Refused],
            "no bitrate yet"
        );
        assert_eq!(send(&mut a, b"S6\rZ1\rO\r").0, vec![Event::Ok; 3]);
        assert!(a.is_open());
        assert_eq!(a.bitrate(), Some(Bitrate::K500));
        assert_eq!(
            send(&mut a, b"S4\rZ0\rO\r").0,
            vec![Event::Refused; 3],
            "bitrate, timestamps and a second open while open"
        );
        assert_eq!(send(&mut a, b"C\rS4\r").0, vec![Event::Ok; 2]);
        assert_eq!(a.bitrate(), Some(Bitrate::K125));
    }

    #[test]
    fn bring_up_joins_the_bus_from_a_fresh_adapter_and_from_one_left_open() {
        let bytes: Vec<u8> = bring_up(Bitrate::K500, true)
            .iter()
            .flat_map(encode_command)
            .collect();
        let mut fresh = Adapter::new(Instant::now());
        assert_eq!(send(&mut fresh, &bytes).0, vec![Event::Ok; 4]);
        assert!(fresh.is_open());
        let mut left_open = Adapter::new(Instant::now());
        send(&mut left_open, b"S4\rO\r");
        assert_eq!(send(&mut left_open, &bytes).0, vec![Event::Ok; 4]);
        assert_eq!(left_open.bitrate(), Some(Bitrate::K500));
        // Without the close, an adapter left open refuses the bitrate.
        let mut again = Adapter::new(Instant::now());
        send(&mut again, b"S4\rO\r");
        assert_eq!(send(&mut again, &bytes[2..]).0[0], Event::Refused);
    }

    #[test]
    fn frames_go_out_only_while_open_and_are_acknowledged() {
        let mut a = Adapter::new(Instant::now());
        let f = Frame::new(Id::Standard(0x72), &[5, 0xCC]).unwrap();
        let line = encode_command(&Command::Transmit(f));
        let (ev, bus) = send(&mut a, &line);
        assert_eq!((ev, bus), (vec![Event::Refused], vec![]), "closed");
        send(&mut a, b"S6\rO\r");
        let (ev, bus) = send(&mut a, &line);
        assert_eq!(ev, vec![Event::Sent { extended: false }]);
        assert_eq!(bus, vec![f]);
        let x = Frame::new(Id::Extended(0x18DA_F110), &[1]).unwrap();
        let (ev, _) = send(&mut a, &encode_command(&Command::Transmit(x)));
        assert_eq!(ev, vec![Event::Sent { extended: true }]);
        // Listening only, nothing goes out.
        send(&mut a, b"C\rL\r");
        assert_eq!(send(&mut a, &line), (vec![Event::Refused], vec![]));
    }

    #[test]
    fn a_bad_command_is_answered_with_bel_and_the_next_one_works() {
        let mut a = Adapter::new(Instant::now());
        let (ev, _) = send(&mut a, b"Q\rS9\rt8000\rS6\r");
        assert_eq!(
            ev,
            vec![Event::Refused, Event::Refused, Event::Refused, Event::Ok]
        );
        assert_eq!(
            send(&mut a, b"V\rN\r").0,
            vec![Event::Version(VERSION), Event::Serial(SERIAL)]
        );
    }

    #[test]
    fn received_frames_reach_the_host_while_open_with_wrapping_timestamps() {
        let t0 = Instant::now();
        let mut a = Adapter::new(t0);
        let f = Frame::new(Id::Standard(0x73), &[5, 0xCC, 1, 0, 0, 0, 0, 0]).unwrap();
        let mut out = Vec::new();
        a.deliver(&f, t0, &mut out);
        assert!(out.is_empty(), "closed: nothing");
        send(&mut a, b"S6\rZ1\rO\r");
        a.deliver(&f, t0 + Duration::from_millis(61_234), &mut out);
        assert_eq!(
            events(&out),
            vec![Event::Received {
                frame: f,
                timestamp: Some(1_234)
            }]
        );
    }

    #[test]
    fn a_bus_fault_refuses_frames_delivers_none_and_shows_in_the_status() {
        let t0 = Instant::now();
        let mut a = Adapter::new(t0);
        send(&mut a, b"S6\rO\r");
        assert_eq!(send(&mut a, b"F\r").0, vec![Event::Status(StatusFlags(0))]);
        a.set_bus_fault(true);
        let f = Frame::new(Id::Standard(0x72), &[5, 0xCC]).unwrap();
        assert_eq!(
            send(&mut a, &encode_command(&Command::Transmit(f))),
            (vec![Event::Refused], vec![])
        );
        let mut out = Vec::new();
        a.deliver(&f, t0, &mut out);
        assert!(out.is_empty());
        let Event::Status(flags) = send(&mut a, b"F\r").0[0] else {
            panic!("a status")
        };
        assert_eq!(flags.to_string(), "error passive, bus error");
        a.set_bus_fault(false);
        send(&mut a, b"F\r");
        assert_eq!(send(&mut a, b"F\r").0, vec![Event::Status(StatusFlags(0))]);
    }
}
