//! The SLCAN (Lawicel) line protocol as pure functions: what the host tells a serial-line
//! CAN adapter (CANable, USBtin, the Lawicel CANUSB and their many clones) and what the
//! adapter answers, as bytes.
//!
//! Every command is ASCII ending in CR: `S6` (500 kbit/s), `O` (open the channel), `C`
//! (close it), `Z1` (timestamps on), `F` (status flags), `t0728…` (send a standard
//! frame), `T18DAF1108…` (an extended one), `r`/`R` (remote requests). The adapter
//! answers CR for done, BEL (0x07, no CR) for refused, `z`/`Z` CR for a frame taken for
//! transmission, `Fxx` CR for its status, and sends every frame it receives from the bus
//! as the same `t`/`T`/`r`/`R` line, followed by a 16-bit millisecond timestamp (four
//! hex digits, wrapping at 60 000) when timestamps are on. Both directions are byte
//! streams that trickle in: [`Decoder`] takes bytes as they come and gives whole items,
//! the same whatever the split, and resynchronises at the next CR after noise.

use crate::can::{Frame, Id};
use arrayvec::ArrayVec;
use std::fmt;

/// Ends every command and every answer but BEL.
pub const CR: u8 = b'\r';
/// The adapter's "refused" (an unknown command, a frame while closed, a bitrate while
/// open, a full transmit buffer).
pub const BEL: u8 = 0x07;
/// The longest line either side sends: `T` + 8 id digits + length + 16 data digits + 4
/// timestamp digits + CR.
pub const MAX_LINE: usize = 31;
/// Timestamps count milliseconds and wrap here.
pub const TIMESTAMP_WRAP: u16 = 60_000;

/// One line on the wire, without its allocation.
pub type Line = ArrayVec<u8, MAX_LINE>;

pub use crate::can::Bitrate;

/// The adapter's status flags (the answer to `F`), one bit each as the Lawicel CANUSB
/// defines them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct StatusFlags(pub u8);

impl StatusFlags {
    pub const RX_FIFO_FULL: u8 = 1 << 0;
    pub const TX_FIFO_FULL: u8 = 1 << 1;
    pub const ERROR_WARNING: u8 = 1 << 2;
    pub const DATA_OVERRUN: u8 = 1 << 3;
    pub const ERROR_PASSIVE: u8 = 1 << 5;
    pub const ARBITRATION_LOST: u8 = 1 << 6;
    pub const BUS_ERROR: u8 = 1 << 7;
    const NAMES: [(u8, &'static str); 7] = [
        (Self::RX_FIFO_FULL, "receive buffer full"),
        (Self::TX_FIFO_FULL, "transmit buffer full"),
        (Self::ERROR_WARNING, "error warning"),
        (Self::DATA_OVERRUN, "data overrun"),
        (Self::ERROR_PASSIVE, "error passive"),
        (Self::ARBITRATION_LOST, "arbitration lost"),
        (Self::BUS_ERROR, "bus error"),
    ];

    /// True when the adapter reports trouble with the bus (anything but an empty
    /// status).
    pub fn any(self) -> bool {
        self.0 != 0
    }

    /// The flags set, in words (`error passive, bus error`).
    pub fn names(self) -> impl Iterator<Item = &'static str> {
        StatusFlags::NAMES
            .into_iter()
            .filter(move |&(bit, _)| self.0 & bit != 0)
            .map(|(_, name)| name)
    }
}

impl fmt::Display for StatusFlags {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if !self.any() {
            return f.write_str("ok");
        }
        let mut first = true;
        for name in self.names() {
            if !first {
                f.write_str(", ")?;
            }
            f.write_str(name)?;
            first = false;
        }
        Ok(())
    }
}

/// What the host tells the adapter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Command {
    /// `O`: open the channel (join the bus).
    Open,
    /// `L`: open the channel listening only (no acknowledgements, no transmissions).
    ListenOnly,
    /// `C`: close the channel.
    Close,
    /// `S0` … `S8`: the bus bitrate (only while closed).
    Bitrate(Bitrate),
    /// `Z0` / `Z1`: timestamps on received frames.
    Timestamps(bool),
    /// `F`: read and clear the status flags.
    Status,
    /// `V`: the hardware and software version.
    Version,
    /// `N`: the serial number.
    Serial,
    /// `t`, `T`, `r`, `R`: send a frame.
    Transmit(Frame),
    /// An empty line: nothing to do, answered with CR (hosts send one to flush a
    /// half-typed command).
    Nothing,
}

/// What the adapter sends the host.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Event {
    /// CR: the command was done.
    Ok,
    /// BEL: the command was refused.
    Refused,
    /// `z` / `Z` CR: a standard / extended frame was taken for transmission.
    Sent { extended: bool },
    /// A frame from the bus, with the adapter's millisecond timestamp when they are on.
    Received {
        frame: Frame,
        timestamp: Option<u16>,
    },
    /// `Fxx` CR: the status flags.
    Status(StatusFlags),
    /// `Vhhss` CR: the version.
    Version([u8; 4]),
    /// `Nxxxx` CR: the serial number.
    Serial([u8; 4]),
    /// A line that is none of these (noise, a clone's own answer), up to its CR.
    Garbled(Line),
}

/// A line the adapter cannot take as a command (answered with BEL).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BadCommand(pub Line);

impl fmt::Display for BadCommand {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "bad command {:?}", String::from_utf8_lossy(&self.0))
    }
}

fn hex_digit(n: u32) -> u8 {
    b"0123456789ABCDEF"[(n & 0xF) as usize]
}

fn push_hex(line: &mut Line, value: u32, digits: u32) {
    for i in (0..digits).rev() {
        line.push(hex_digit(value >> (4 * i)));
    }
}

fn parse_hex(text: &[u8]) -> Option<u32> {
    if text.is_empty() || text.len() > 8 {
        return None;
    }
    text.iter().try_fold(0u32, |acc, &c| {
        let d = (c as char).to_digit(16)?;
        Some(acc << 4 | d)
    })
}

/// A frame as its `t`/`T`/`r`/`R` text, without CR.
fn push_frame(line: &mut Line, frame: &Frame) {
    let (letter, digits) = match (frame.id(), frame.is_remote()) {
        (Id::Standard(_), false) => (b't', 3),
        (Id::Extended(_), false) => (b'T', 8),
        (Id::Standard(_), true) => (b'r', 3),
        (Id::Extended(_), true) => (b'R', 8),
    };
    line.push(letter);
    push_hex(line, frame.id().raw(), digits);
    line.push(hex_digit(frame.len() as u32));
    for &b in frame.data() {
        push_hex(line, b as u32, 2);
    }
}

/// A `t`/`T`/`r`/`R` line (without CR) as a frame and, after it, a timestamp if the line
/// carries four more hex digits and `timestamps` allows them.
fn parse_frame(line: &[u8], timestamps: bool) -> Option<(Frame, Option<u16>)> {
    let (&letter, rest) = line.split_first()?;
    let (extended, remote) = match letter {
        b't' => (false, false),
        b'T' => (true, false),
        b'r' => (false, true),
        b'R' => (true, true),
        _ => return None,
    };
    let digits = if extended { 8 } else { 3 };
    if rest.len() < digits + 1 {
        return None;
    }
    let raw = parse_hex(&rest[..digits])?;
    let id = if extended {
        Id::extended(raw)?
    } else {
        Id::standard(u16::try_from(raw).ok()?)?
    };
    let len = parse_hex(&rest[digits..digits + 1])? as u8;
    if len > 8 {
        return None;
    }
    let mut rest = &rest[digits + 1..];
    let frame = if remote {
        Frame::remote(id, len)?
    } else {
        let bytes = 2 * len as usize;
        if rest.len() < bytes {
            return None;
        }
        let mut data = [0u8; 8];
        for (i, pair) in rest[..bytes].chunks(2).enumerate() {
            data[i] = parse_hex(pair)? as u8;
        }
        rest = &rest[bytes..];
        Frame::new(id, &data[..len as usize])?
    };
    match rest.len() {
        0 => Some((frame, None)),
        4 if timestamps => Some((frame, Some(u16::try_from(parse_hex(rest)?).ok()?))),
        _ => None,
    }
}

/// The commands that bring an adapter onto the bus at `bitrate` whatever state a
/// previous run left it in: close first (an adapter left open refuses a bitrate), then
/// the bitrate, timestamps on or off, open. Each is answered CR; a BEL for any but the
/// first means the adapter cannot join the bus that way.
pub fn bring_up(bitrate: Bitrate, timestamps: bool) -> [Command; 4] {
    [
        Command::Close,
        Command::Bitrate(bitrate),
        Command::Timestamps(timestamps),
        Command::Open,
    ]
}

/// The bytes of a command, CR included.
pub fn encode_command(command: &Command) -> Line {
    let mut line = Line::new();
    match *command {
        Command::Open => line.push(b'O'),
        Command::ListenOnly => line.push(b'L'),
        Command::Close => line.push(b'C'),
        Command::Bitrate(b) => {
            line.push(b'S');
            line.push(b'0' + b.code());
        }
        Command::Timestamps(on) => {
            line.push(b'Z');
            line.push(if on { b'1' } else { b'0' });
        }
        Command::Status => line.push(b'F'),
        Command::Version => line.push(b'V'),
        Command::Serial => line.push(b'N'),
        Command::Transmit(ref frame) => push_frame(&mut line, frame),
        Command::Nothing => {}
    }
    line.push(CR);
    line
}

/// The bytes of an adapter's answer or received frame (the simulated adapter's side).
pub fn encode_event(event: &Event) -> Line {
    let mut line = Line::new();
    match event {
        Event::Ok => {}
        Event::Refused => {
            line.push(BEL);
            return line;
        }
        Event::Sent { extended } => line.push(if *extended { b'Z' } else { b'z' }),
        Event::Received { frame, timestamp } => {
            push_frame(&mut line, frame);
            if let Some(t) = timestamp {
                push_hex(&mut line, *t as u32, 4);
            }
        }
        Event::Status(flags) => {
            line.push(b'F');
            push_hex(&mut line, flags.0 as u32, 2);
        }
        Event::Version(v) => {
            line.push(b'V');
            line.extend(v.iter().copied());
        }
        Event::Serial(n) => {
            line.push(b'N');
            line.extend(n.iter().copied());
        }
        Event::Garbled(text) => line.extend(text.iter().copied().take(MAX_LINE - 1)),
    }
    line.push(CR);
    line
}

/// One line of an adapter's output (without its CR) as an event.
pub fn decode_event(line: &[u8]) -> Event {
    let garbled = || Event::Garbled(line.iter().copied().take(MAX_LINE).collect());
    match line {
        [] => Event::Ok,
        [b'z'] => Event::Sent { extended: false },
        [b'Z'] => Event::Sent { extended: true },
        [b'F', a, b] => {
            parse_hex(&[*a, *b]).map_or_else(garbled, |v| Event::Status(StatusFlags(v as u8)))
        }
        [b'V', rest @ ..] if rest.len() == 4 => {
            Event::Version([rest[0], rest[1], rest[2], rest[3]])
        }
        [b'N', rest @ ..] if rest.len() == 4 => Event::Serial([rest[0], rest[1], rest[2], rest[3]]),
        _ => match parse_frame(line, true) {
            Some((frame, timestamp)) => Event::Received { frame, timestamp },
            None => garbled(),
        },
    }
}

/// One line of a host's input (without its CR) as a command (the adapter's side).
pub fn decode_command(line: &[u8]) -> Result<Command, BadCommand> {
    let bad = || BadCommand(line.iter().copied().take(MAX_LINE).collect());
    match line {
        [] => Ok(Command::Nothing),
        [b'O'] => Ok(Command::Open),
        [b'L'] => Ok(Command::ListenOnly),
        [b'C'] => Ok(Command::Close),
        [b'F'] => Ok(Command::Status),
        [b'V'] => Ok(Command::Version),
        [b'N'] => Ok(Command::Serial),
        [b'S', d] => d
            .checked_sub(b'0')
            .and_then(Bitrate::from_code)
            .map(Command::Bitrate)
            .ok_or_else(bad),
        [b'Z', b'0'] => Ok(Command::Timestamps(false)),
        [b'Z', b'1'] => Ok(Command::Timestamps(true)),
        _ => parse_frame(line, false)
            .map(|(frame, _)| Command::Transmit(frame))
            .ok_or_else(bad),
    }
}

/// Which way a [`Decoder`] reads.
pub trait Direction {
    type Item;
    /// What BEL is when it ends an item on its own (the adapter's refusal, which drops
    /// any noise before it); `None` on the host's side, where it is just a byte of a
    /// bad command.
    fn bel() -> Option<Self::Item>;
    fn decode(line: &[u8]) -> Self::Item;
    /// What a run of `MAX_LINE` bytes without a terminator is.
    fn overlong(line: &[u8]) -> Self::Item;
}

/// Reading what an adapter sends (the host's side): [`Event`]s.
#[derive(Debug)]
pub enum FromAdapter {}

impl Direction for FromAdapter {
    type Item = Event;
    fn bel() -> Option<Event> {
        Some(Event::Refused)
    }
    fn decode(line: &[u8]) -> Event {
        decode_event(line)
    }
    fn overlong(line: &[u8]) -> Event {
        Event::Garbled(line.iter().copied().take(MAX_LINE).collect())
    }
}

/// Reading what a host sends (the adapter's side): [`Command`]s or what is wrong.
#[derive(Debug)]
pub enum FromHost {}

impl Direction for FromHost {
    type Item = Result<Command, BadCommand>;
    fn bel() -> Option<Self::Item> {
        None
    }
    fn decode(line: &[u8]) -> Self::Item {
        decode_command(line)
    }
    fn overlong(line: &[u8]) -> Self::Item {
        Err(BadCommand(line.iter().copied().take(MAX_LINE).collect()))
    }
}

/// An incremental decoder: [`Decoder::push`] the bytes as they arrive, then take whole
/// items with [`Decoder::next`] until it says `None`. A line longer than [`MAX_LINE`]
/// without a CR is given as garbled and skipped up to the next CR, so noise cannot grow
/// the buffer. A line feed at the start of a line is skipped (terminals send CR LF).
#[derive(Debug)]
pub struct Decoder<D: Direction> {
    line: Line,
    /// Skipping the rest of an overlong line, up to its CR.
    skipping: bool,
    pending: Vec<u8>,
    at: usize,
    _direction: std::marker::PhantomData<D>,
}

impl<D: Direction> Default for Decoder<D> {
    fn default() -> Self {
        Decoder {
            line: Line::new(),
            skipping: false,
            pending: Vec::new(),
            at: 0,
            _direction: std::marker::PhantomData,
        }
    }
}

impl<D: Direction> Decoder<D> {
    pub fn new() -> Self {
        Self::default()
    }

    /// Bytes as they arrived.
    pub fn push(&mut self, bytes: &[u8]) {
        if self.at == self.pending.len() {
            self.pending.clear();
            self.at = 0;
        }
        self.pending.extend_from_slice(bytes);
    }

    /// The next whole item, if the bytes pushed so far complete one.
    #[allow(clippy::should_implement_trait)]
    pub fn next(&mut self) -> Option<D::Item> {
        while self.at < self.pending.len() {
            let b = self.pending[self.at];
            self.at += 1;
            if self.skipping {
                self.skipping = b != CR;
                continue;
            }
            match b {
                CR => {
                    let item = D::decode(&self.line);
                    self.line.clear();
                    return Some(item);
                }
                BEL if D::bel().is_some() => {
                    self.line.clear();
                    return D::bel();
                }
                b'\n' if self.line.is_empty() => {}
                _ => {
                    if self.line.try_push(b).is_err() {
                        let item = D::overlong(&self.line);
                        self.line.clear();
                        self.skipping = true;
                        return Some(item);
                    }
                }
            }
        }
        None
    }

    /// The bytes of an unfinished line held so far.
    pub fn partial(&self) -> &[u8] {
        &self.line
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn std_frame(id: u16, data: &[u8]) -> Frame {
        Frame::new(Id::Standard(id), data).unwrap()
    }

    fn events(bytes: &[u8]) -> Vec<Event> {
        let mut d = Decoder::<FromAdapter>::new();
        d.push(bytes);
        std::iter::from_fn(|| d.next()).collect()
    }

    fn commands(bytes: &[u8]) -> Vec<Result<Command, BadCommand>> {
        let mut d = Decoder::<FromHost>::new();
        d.push(bytes);
        std::iter::from_fn(|| d.next()).collect()
    }

    #[test]
    fn commands_are_the_lawicel_text() {
        let cases: [(Command, &[u8]); 9] = [
            (Command::Open, b"O\r"),
            (Command::Close, b"C\r"),
            (Command::ListenOnly, b"L\r"),
            (Command::Bitrate(Bitrate::K500), b"S6\r"),
            (Command::Bitrate(Bitrate::M1), b"S8\r"),
            (Command::Timestamps(true), b"Z1\r"),
            (Command::Timestamps(false), b"Z0\r"),
            (Command::Status, b"F\r"),
            (
                Command::Transmit(std_frame(0x72, &[0x05, 0xCC, 0, 0, 0x80, 0x3E, 0, 0])),
                b"t072805CC0000803E0000\r",
            ),
        ];
        for (command, bytes) in cases {
            assert_eq!(&*encode_command(&command), bytes, "{command:?}");
            assert_eq!(commands(bytes), vec![Ok(command)]);
        }
    }

    #[test]
    fn extended_and_remote_frames() {
        let ext = Frame::new(Id::Extended(0x18DA_F110), &[0x02, 0x01, 0x0D]).unwrap();
        let bytes = encode_command(&Command::Transmit(ext));
        assert_eq!(&*bytes, b"T18DAF110302010D\r");
        let r = Frame::remote(Id::Standard(0x7DF), 8).unwrap();
        assert_eq!(&*encode_command(&Command::Transmit(r)), b"r7DF8\r");
        let rx = Frame::remote(Id::Extended(0x100), 0).unwrap();
        assert_eq!(&*encode_command(&Command::Transmit(rx)), b"R000001000\r");
        assert_eq!(
            events(b"r7DF8\rR0000010001234\r"),
            vec![
                Event::Received {
                    frame: r,
                    timestamp: None
                },
                Event::Received {
                    frame: rx,
                    timestamp: Some(0x1234)
                }
            ]
        );
    }

    #[test]
    fn the_adapter_answers_acks_refusals_status_and_frames_with_timestamps() {
        let got = events(b"\r\x07z\rZ\rF84\rV1013\rNA1B2\rt0738050C01000000000012EA\r");
        assert_eq!(
            got,
            vec![
                Event::Ok,
                Event::Refused,
                Event::Sent { extended: false },
                Event::Sent { extended: true },
                Event::Status(StatusFlags(0x84)),
                Event::Version(*b"1013"),
                Event::Serial(*b"A1B2"),
                Event::Received {
                    frame: std_frame(0x73, &[0x05, 0x0C, 0x01, 0, 0, 0, 0, 0]),
                    timestamp: Some(0x12EA)
                },
            ]
        );
        let Event::Status(flags) = &got[4] else {
            unreachable!()
        };
        assert_eq!(flags.to_string(), "error warning, bus error");
    }

    #[test]
    fn bad_commands_are_named_and_the_stream_goes_on() {
        // An 11-bit id too large, a length over 8, data short of its length, a
        // bitrate code past S8, a letter no adapter knows; then a good command.
        let got = commands(b"t8001FF\rt0729\rt0722000\rS9\rx\rO\r");
        assert_eq!(got.len(), 6);
        assert!(got[..5].iter().all(|c| c.is_err()), "{got:?}");
        assert_eq!(got[5], Ok(Command::Open));
        assert_eq!(
            got[0].as_ref().unwrap_err().to_string(),
            "bad command \"t8001FF\""
        );
        // A host cannot send timestamps: the adapter takes four more digits as wrong.
        assert!(commands(b"t0720FFFF\r")[0].is_err());
    }

    #[test]
    fn noise_without_a_terminator_is_bounded_and_the_next_line_decodes() {
        let mut bytes = vec![b'q'; 200];
        bytes.extend_from_slice(b"\rt0731AA\r");
        let got = events(&bytes);
        assert!(matches!(got[0], Event::Garbled(ref l) if l.len() == MAX_LINE));
        assert_eq!(
            got[1],
            Event::Received {
                frame: std_frame(0x73, &[0xAA]),
                timestamp: None
            }
        );
        assert_eq!(got.len(), 2, "{got:?}");
    }

    #[test]
    fn line_feeds_after_cr_are_skipped_and_bel_drops_noise_before_it() {
        assert_eq!(
            events(b"z\r\nz\r\n"),
            vec![
                Event::Sent { extended: false },
                Event::Sent { extended: false }
            ]
        );
        assert_eq!(events(b"t0\x07"), vec![Event::Refused]);
        assert_eq!(
            commands(b"O\r\nC\r\n"),
            vec![Ok(Command::Open), Ok(Command::Close)]
        );
    }

    #[test]
    fn bitrates_by_code_and_by_bits_per_second() {
        for (i, b) in Bitrate::ALL.into_iter().enumerate() {
            assert_eq!(b.code() as usize, i);
            assert_eq!(Bitrate::from_bits_per_second(b.bits_per_second()), Some(b));
        }
        assert_eq!(Bitrate::K500.bits_per_second(), 500_000);
        assert_eq!(Bitrate::from_bits_per_second(333_333), None);
    }

    fn any_id() -> impl Strategy<Value = Id> {
        prop_oneof![
            (0u16..=0x7FF).prop_map(Id::Standard),
            (0u32..=0x1FFF_FFFF).prop_map(Id::Extended),
        ]
    }

    fn any_frame() -> impl Strategy<Value = Frame> {
        prop_oneof![
            (any_id(), proptest::collection::vec(any::<u8>(), 0..=8))
                .prop_map(|(id, data)| Frame::new(id, &data).unwrap()),
            (any_id(), 0u8..=8).prop_map(|(id, len)| Frame::remote(id, len).unwrap()),
        ]
    }

    fn any_event() -> impl Strategy<Value = Event> {
        prop_oneof![
            Just(Event::Ok),
            Just(Event::Refused),
            any::<bool>().prop_map(|extended| Event::Sent { extended }),
            (any_frame(), proptest::option::of(0u16..TIMESTAMP_WRAP))
                .prop_map(|(frame, timestamp)| Event::Received { frame, timestamp }),
            any::<u8>().prop_map(|f| Event::Status(StatusFlags(f))),
        ]
    }

    fn any_command() -> impl Strategy<Value = Command> {
        prop_oneof![
            Just(Command::Open),
            Just(Command::Close),
            Just(Command::ListenOnly),
            Just(Command::Status),
            Just(Command::Version),
            Just(Command::Serial),
            Just(Command::Nothing),
            (0u8..=8).prop_map(|c| Command::Bitrate(Bitrate::from_code(c).unwrap())),
            any::<bool>().prop_map(Command::Timestamps),
            any_frame().prop_map(Command::Transmit),
        ]
    }

    /// Feed `bytes` in pieces cut at `cuts` (positions, any order) and collect items.
    fn split_decode<D: Direction>(bytes: &[u8], cuts: &[usize]) -> Vec<D::Item> {
        let mut cuts: Vec<usize> = cuts.iter().map(|c| c % (bytes.len() + 1)).collect();
        cuts.push(0);
        cuts.push(bytes.len());
        cuts.sort_unstable();
        let mut d = Decoder::<D>::new();
        let mut out = Vec::new();
        for w in cuts.windows(2) {
            d.push(&bytes[w[0]..w[1]]);
            out.extend(std::iter::from_fn(|| d.next()));
        }
        out
    }

    proptest! {
        #[test]
        fn adapter_events_round_trip_whatever_the_split(
            evs in proptest::collection::vec(any_event(), 0..20),
            cuts in proptest::collection::vec(any::<usize>(), 0..12),
        ) {
            let bytes: Vec<u8> = evs.iter().flat_map(encode_event).collect();
            prop_assert_eq!(&split_decode::<FromAdapter>(&bytes, &cuts), &evs);
        }

        #[test]
        fn host_commands_round_trip_whatever_the_split(
            cmds in proptest::collection::vec(any_command(), 0..20),
            cuts in proptest::collection::vec(any::<usize>(), 0..12),
        ) {
            let bytes: Vec<u8> = cmds.iter().flat_map(encode_command).collect();
            let want: Vec<_> = cmds.into_iter().map(Ok).collect();
            prop_assert_eq!(split_decode::<FromHost>(&bytes, &cuts), want);
        }

        #[test]
        fn any_bytes_decode_the_same_whatever_the_split(
            bytes in proptest::collection::vec(
                prop_oneof![Just(b'\r'), Just(0x07u8), Just(b't'), Just(b'0'), any::<u8>()],
                0..200,
            ),
            cuts in proptest::collection::vec(any::<usize>(), 0..12),
        ) {
            prop_assert_eq!(
                split_decode::<FromAdapter>(&bytes, &cuts),
                split_decode::<FromAdapter>(&bytes, &[])
            );
            prop_assert_eq!(
                split_decode::<FromHost>(&bytes, &cuts),
                split_decode::<FromHost>(&bytes, &[])
            );
        }
    }
}
