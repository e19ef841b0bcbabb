//! CAN as adrive speaks it, below every link and every front end: a [`Frame`] (an
//! identifier and up to eight data bytes) and [`dbc`], the messages and signals a DBC
//! file describes.
//!
//! A frame is the same whatever carries it: the SLCAN adapter's text lines
//! ([`crate::driver::slcan`]), SocketCAN later, the simulator's kit, the bench view's
//! monitor. So it lives here, beside the DBC that gives its bytes a meaning, and
//! imports nothing of the crate: drivers, the simulator and the console import it.

pub mod dbc;

use std::fmt;

/// The largest standard (11-bit) identifier.
pub const STANDARD_MAX: u16 = 0x7FF;
/// The largest extended (29-bit) identifier.
pub const EXTENDED_MAX: u32 = 0x1FFF_FFFF;

/// A CAN identifier: 11 bits (standard) or 29 bits (extended). The same number in the
/// two forms names two different messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Id {
    Standard(u16),
    Extended(u32),
}

impl Id {
    /// A standard identifier, if `id` fits in 11 bits.
    pub fn standard(id: u16) -> Option<Id> {
        (id <= STANDARD_MAX).then_some(Id::Standard(id))
    }

    /// An extended identifier, if `id` fits in 29 bits.
    pub fn extended(id: u32) -> Option<Id> {
        (id <= EXTENDED_MAX).then_some(Id::Extended(id))
    }

    /// The identifier's number, without its form.
    pub fn raw(self) -> u32 {
        match self {
            Id::Standard(id) => id as u32,
            Id::Extended(id) => id,
        }
    }

    pub fn is_extended(self) -> bool {
        matches!(self, Id::Extended(_))
    }
}

impl fmt::Display for Id {
    /// `0x072`, `0x18DAF110x` (the `x` marks the extended form, as candump's `#`
    /// notation does with eight digits).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Id::Standard(id) => write!(f, "0x{id:03X}"),
            Id::Extended(id) => write!(f, "0x{id:08X}x"),
        }
    }
}

/// One classic CAN frame: a data frame with 0 to 8 bytes, or a remote request for
/// `len` bytes.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Frame {
    id: Id,
    len: u8,
    data: [u8; 8],
    remote: bool,
}

impl Frame {
    /// A data frame; `None` when `data` has more than eight bytes.
    pub fn new(id: Id, data: &[u8]) -> Option<Frame> {
        if data.len() > 8 {
            return None;
        }
        let mut bytes = [0u8; 8];
        bytes[..data.len()].copy_from_slice(data);
        Some(Frame {
            id,
            len: data.len() as u8,
            data: bytes,
            remote: false,
        })
    }

    /// A remote request for `len` bytes (at most 8).
    pub fn remote(id: Id, len: u8) -> Option<Frame> {
        (len <= 8).then_some(Frame {
            id,
            len,
            data: [0; 8],
            remote: true,
        })
    }

    pub fn id(&self) -> Id {
        self.id
    }

    /// The data bytes (empty for a remote request).
    pub fn data(&self) -> &[u8] {
        if self.remote {
            &[]
        } else {
            &self.data[..self.len as usize]
        }
    }

    /// The data bytes, to fill in (a rolling counter, a checksum); empty for a remote
    /// request.
    pub fn data_mut(&mut self) -> &mut [u8] {
        if self.remote {
            &mut []
        } else {
            &mut self.data[..self.len as usize]
        }
    }

    /// The data length code: the number of data bytes, or the length a remote request
    /// asks for.
    pub fn len(&self) -> usize {
        self.len as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn is_remote(&self) -> bool {
        self.remote
    }

    /// How many bit times the frame holds the bus, the interframe space included: 47
    /// bits of framing (67 with a 29-bit identifier) and 8 a data byte, plus, in the
    /// worst case, one stuff bit after every four bits from the start of frame to the
    /// end of the CRC (ISO 11898-1). At 500 kbit/s an 8-byte standard frame takes
    /// 111 bits (222 µs), 135 (270 µs) stuffed at worst.
    pub fn wire_bits(&self, worst_case_stuffing: bool) -> u32 {
        let data = if self.remote { 0 } else { 8 * self.len as u32 };
        let (framing, stuffed) = match self.id {
            Id::Standard(_) => (47, 34),
            Id::Extended(_) => (67, 54),
        };
        let stuffing = if worst_case_stuffing {
            (stuffed + data - 1) / 4
        } else {
            0
        };
        framing + data + stuffing
    }
}

impl fmt::Debug for Frame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(self, f)
    }
}

impl fmt::Display for Frame {
    /// `0x072 [8] 05 CC 00 00 00 3F 00 00`, `0x072 [8] remote`, as candump prints.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} [{}]", self.id, self.len)?;
        if self.remote {
            return f.write_str(" remote");
        }
        for b in self.data() {
            write!(f, " {b:02X}")?;
        }
        Ok(())
    }
}

/// The standard CAN bitrates, as serial-line adapters number them (`S0` … `S8`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Bitrate {
    K10,
    K20,
    K50,
    K100,
    K125,
    K250,
    K500,
    K800,
    M1,
}

impl Bitrate {
    pub const ALL: [Bitrate; 9] = [
        Bitrate::K10,
        Bitrate::K20,
        Bitrate::K50,
        Bitrate::K100,
        Bitrate::K125,
        Bitrate::K250,
        Bitrate::K500,
        Bitrate::K800,
        Bitrate::M1,
    ];

    /// The digit after `S`.
    pub fn code(self) -> u8 {
        Bitrate::ALL.iter().position(|&b| b == self).unwrap_or(0) as u8
    }

    pub fn from_code(code: u8) -> Option<Bitrate> {
        Bitrate::ALL.get(code as usize).copied()
    }

    pub fn bits_per_second(self) -> u32 {
        match self {
            Bitrate::K10 => 10_000,
            Bitrate::K20 => 20_000,
            Bitrate::K50 => 50_000,
            Bitrate::K100 => 100_000,
            Bitrate::K125 => 125_000,
            Bitrate::K250 => 250_000,
            Bitrate::K500 => 500_000,
            Bitrate::K800 => 800_000,
            Bitrate::M1 => 1_000_000,
        }
    }

    /// The standard bitrate of exactly `bps` bits per second (a vehicle file's `500000`).
    pub fn from_bits_per_second(bps: u32) -> Option<Bitrate> {
        Bitrate::ALL
            .into_iter()
            .find(|b| b.bits_per_second() == bps)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identifiers_keep_to_their_width() {
        assert_eq!(Id::standard(0x7FF), Some(Id::Standard(0x7FF)));
        assert_eq!(Id::standard(0x800), None);
        assert_eq!(Id::extended(0x1FFF_FFFF), Some(Id::Extended(0x1FFF_FFFF)));
        assert_eq!(Id::extended(0x2000_0000), None);
        assert_ne!(Id::Standard(0x70), Id::Extended(0x70));
    }

    #[test]
    fn wire_time_of_a_frame() {
        let full = Frame::new(Id::Standard(0x72), &[0; 8]).unwrap();
        assert_eq!(full.wire_bits(false), 111);
        assert_eq!(full.wire_bits(true), 135);
        let ext = Frame::new(Id::Extended(0x18DA_F110), &[0; 8]).unwrap();
        assert_eq!(ext.wire_bits(false), 131);
        assert_eq!(ext.wire_bits(true), 160);
        let empty = Frame::new(Id::Standard(1), &[]).unwrap();
        assert_eq!(empty.wire_bits(false), 47);
        assert_eq!(
            Frame::remote(Id::Standard(1), 8).unwrap().wire_bits(false),
            47
        );
    }

    #[test]
    fn a_frame_holds_at_most_eight_bytes_and_prints_as_candump_does() {
        assert!(Frame::new(Id::Standard(1), &[0; 9]).is_none());
        let f = Frame::new(Id::Standard(0x72), &[0x05, 0xCC, 0, 0, 0, 0x3F, 0, 0]).unwrap();
        assert_eq!(f.to_string(), "0x072 [8] 05 CC 00 00 00 3F 00 00");
        let r = Frame::remote(Id::Extended(0x18DA_F110), 2).unwrap();
        assert_eq!(r.to_string(), "0x18DAF110x [2] remote");
        assert!(r.data().is_empty());
        assert_eq!(r.len(), 2);
    }
}
