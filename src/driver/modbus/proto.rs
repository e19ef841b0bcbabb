//! Modbus RTU framing, both sides, as pure functions on bytes: request and response
//! encoding, decoding with every check a master or a slave must make (slave id,
//! function code, byte count, CRC), exception replies, and where a frame ends when
//! there is no silence on the line to tell.
//!
//! Why hand-written: the checksum comes from the `crc` crate (`CRC_16_MODBUS`), and the
//! rest is the four function codes adrive uses, about two hundred lines. `rmodbus` was
//! considered: its client builds and parses frames well, but its server is built around
//! its own register memory (`ModbusContext`) rather than a live device model, its frame
//! length guess panics on a short buffer in the versions looked at, and its errors do
//! not separate "wrong slave id" from "bad CRC", which the engine counts apart.
//! `modbus-core` is close too, but brings its own `byteorder` types for little gain.
//! A request frame is built on the stack ([`Frame`]): the command path from a
//! datagram to the wire allocates nothing. Replies and the slave's side use `Vec`.
//!
//! Reference: MODBUS Application Protocol V1.1b3 and MODBUS over Serial Line V1.02.

use std::fmt;
use std::time::Duration;

/// Function 03: read holding registers.
pub(crate) const READ_HOLDING: u8 = 0x03;
/// Function 04: read input registers.
pub(crate) const READ_INPUT: u8 = 0x04;
/// Function 06: write a single holding register.
pub(crate) const WRITE_SINGLE: u8 = 0x06;
/// Function 16: write multiple holding registers.
pub(crate) const WRITE_MULTIPLE: u8 = 0x10;
/// Set in the function code of an exception reply.
pub(crate) const EXCEPTION_BIT: u8 = 0x80;
/// Slave id 0 addresses every slave; nobody answers it.
pub(crate) const BROADCAST: u8 = 0;
/// Most registers one read may ask for (spec: 125).
pub(crate) const MAX_READ: u16 = 125;
/// Most registers one write multiple may carry (spec: 123).
pub(crate) const MAX_WRITE: u16 = 123;
/// Longest RTU frame (spec: 256 bytes).
pub(crate) const MAX_FRAME: usize = 256;

const CRC16: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_MODBUS);

/// CRC-16/MODBUS of `bytes`. On the wire it goes low byte first.
pub(crate) fn crc16(bytes: &[u8]) -> u16 {
    CRC16.checksum(bytes)
}

/// Append the CRC of `frame` to it, low byte first.
pub(crate) fn push_crc(frame: &mut Vec<u8>) {
    let crc = crc16(frame);
    frame.extend_from_slice(&crc.to_le_bytes());
}

/// A request frame, on the stack.
pub type Frame = arrayvec::ArrayVec<u8, MAX_FRAME>;

/// True when the last two bytes of `frame` are the CRC of the rest.
pub(crate) fn crc_ok(frame: &[u8]) -> bool {
    frame.len() >= 4 && {
        let (body, tail) = frame.split_at(frame.len() - 2);
        crc16(body).to_le_bytes() == [tail[0], tail[1]]
    }
}

/// The silence that separates two frames: 3.5 character times of 11 bits at `baud`,
/// and a fixed 1.75 ms above 19200 baud (Serial Line V1.02, 2.5.1.1).
pub(crate) fn frame_gap(baud: u32) -> Duration {
    if baud > 19_200 || baud == 0 {
        Duration::from_micros(1750)
    } else {
        Duration::from_nanos(38_500_000_000 / baud as u64)
    }
}

/// A Modbus exception code, as a slave reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Exception {
    IllegalFunction,
    IllegalDataAddress,
    IllegalDataValue,
    ServerDeviceFailure,
    Acknowledge,
    ServerDeviceBusy,
    MemoryParityError,
    GatewayPathUnavailable,
    GatewayTargetFailed,
    Other(u8),
}

impl Exception {
    pub fn code(self) -> u8 {
        match self {
            Exception::IllegalFunction => 0x01,
            Exception::IllegalDataAddress => 0x02,
            Exception::IllegalDataValue => 0x03,
            Exception::ServerDeviceFailure => 0x04,
            Exception::Acknowledge => 0x05,
            Exception::ServerDeviceBusy => 0x06,
            Exception::MemoryParityError => 0x08,
            Exception::GatewayPathUnavailable => 0x0A,
            Exception::GatewayTargetFailed => 0x0B,
            Exception::Other(c) => c,
        }
    }

    pub(crate) fn from_code(code: u8) -> Exception {
        match code {
            0x01 => Exception::IllegalFunction,
            0x02 => Exception::IllegalDataAddress,
            0x03 => Exception::IllegalDataValue,
            0x04 => Exception::ServerDeviceFailure,
            0x05 => Exception::Acknowledge,
            0x06 => Exception::ServerDeviceBusy,
            0x08 => Exception::MemoryParityError,
            0x0A => Exception::GatewayPathUnavailable,
            0x0B => Exception::GatewayTargetFailed,
            c => Exception::Other(c),
        }
    }

    /// The spec's name for the exception, in lower case.
    pub fn name(self) -> String {
        match self {
            Exception::IllegalFunction => "illegal function".into(),
            Exception::IllegalDataAddress => "illegal data address".into(),
            Exception::IllegalDataValue => "illegal data value".into(),
            Exception::ServerDeviceFailure => "server device failure".into(),
            Exception::Acknowledge => "acknowledge".into(),
            Exception::ServerDeviceBusy => "server device busy".into(),
            Exception::MemoryParityError => "memory parity error".into(),
            Exception::GatewayPathUnavailable => "gateway path unavailable".into(),
            Exception::GatewayTargetFailed => "gateway target device failed to respond".into(),
            Exception::Other(c) => format!("exception {c:#04x}"),
        }
    }
}

impl fmt::Display for Exception {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name())
    }
}

/// A request, without slave id and CRC.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Request {
    ReadHolding { addr: u16, count: u16 },
    ReadInput { addr: u16, count: u16 },
    WriteSingle { addr: u16, value: u16 },
    WriteMultiple { addr: u16, values: Vec<u16> },
}

impl Request {
    pub(crate) fn function(&self) -> u8 {
        match self {
            Request::ReadHolding { .. } => READ_HOLDING,
            Request::ReadInput { .. } => READ_INPUT,
            Request::WriteSingle { .. } => WRITE_SINGLE,
            Request::WriteMultiple { .. } => WRITE_MULTIPLE,
        }
    }
}

/// A normal (non-exception) response, without slave id and CRC.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Response {
    ReadHolding(Vec<u16>),
    ReadInput(Vec<u16>),
    /// The echo of a write single.
    WriteSingle {
        addr: u16,
        value: u16,
    },
    /// The echo of a write multiple: where and how many.
    WriteMultiple {
        addr: u16,
        count: u16,
    },
}

/// Why a frame was not accepted.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub(crate) enum FrameError {
    #[error("truncated frame: {got} of {needed} bytes")]
    Truncated { needed: usize, got: usize },
    #[error("bad CRC: frame carries {received:#06x}, computed {computed:#06x}")]
    BadCrc { received: u16, computed: u16 },
    #[error("reply from slave {got}, expected slave {expected}")]
    WrongSlave { expected: u8, got: u8 },
    #[error("reply to function {got:#04x}, expected function {expected:#04x}")]
    WrongFunction { expected: u8, got: u8 },
    #[error("byte count {got}, expected {expected}")]
    ByteCount { expected: usize, got: usize },
    #[error("frame of {got} bytes, expected {expected}")]
    Length { expected: usize, got: usize },
    #[error("write echo {got:04X?} differs from the request {expected:04X?}")]
    EchoMismatch { expected: [u16; 2], got: [u16; 2] },
    #[error("unknown function code {0:#04x}")]
    UnknownFunction(u8),
    /// The slave answered with an exception: the request reached it and was refused.
    #[error("{exception} (function {function:#04x})")]
    Exception { function: u8, exception: Exception },
}

fn be(bytes: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([bytes[at], bytes[at + 1]])
}

/// The complete RTU frame of a request to `slave`, on the stack.
pub(crate) fn encode_request(slave: u8, request: &Request) -> Frame {
    let mut f = Frame::new();
    f.push(slave);
    f.push(request.function());
    match request {
        Request::ReadHolding { addr, count } | Request::ReadInput { addr, count } => {
            f.extend(addr.to_be_bytes());
            f.extend(count.to_be_bytes());
        }
        Request::WriteSingle { addr, value } => {
            f.extend(addr.to_be_bytes());
            f.extend(value.to_be_bytes());
        }
        Request::WriteMultiple { addr, values } => {
            // At most MAX_WRITE registers fit a frame; the rest are not sent.
            let values = &values[..values.len().min(usize::from(MAX_WRITE))];
            f.extend(addr.to_be_bytes());
            f.extend((values.len() as u16).to_be_bytes());
            f.push((values.len() * 2) as u8);
            for v in values {
                f.extend(v.to_be_bytes());
            }
        }
    }
    let crc = crc16(&f);
    f.extend(crc.to_le_bytes());
    f
}

/// How long the response frame that starts with `head` is, in bytes, once its first
/// three bytes are known (slave id, function, and byte count or first address byte).
/// `Ok(None)`: fewer than three bytes yet.
pub(crate) fn response_len(head: &[u8]) -> Result<Option<usize>, FrameError> {
    if head.len() < 3 {
        return Ok(None);
    }
    let function = head[1];
    Ok(Some(match function {
        f if f & EXCEPTION_BIT != 0 => 5,
        READ_HOLDING | READ_INPUT => 3 + head[2] as usize + 2,
        WRITE_SINGLE | WRITE_MULTIPLE => 8,
        f => return Err(FrameError::UnknownFunction(f)),
    }))
}

/// Check the CRC and the slave id of a complete frame.
fn check_envelope(slave: u8, frame: &[u8], min: usize) -> Result<(), FrameError> {
    if frame.len() < min {
        return Err(FrameError::Truncated {
            needed: min,
            got: frame.len(),
        });
    }
    let (body, tail) = frame.split_at(frame.len() - 2);
    let received = u16::from_le_bytes([tail[0], tail[1]]);
    let computed = crc16(body);
    if received != computed {
        return Err(FrameError::BadCrc { received, computed });
    }
    if frame[0] != slave {
        return Err(FrameError::WrongSlave {
            expected: slave,
            got: frame[0],
        });
    }
    Ok(())
}

/// Decode the complete response `frame` to `request` sent to `slave`. The CRC is checked
/// first (a corrupted id byte is a CRC error, not another slave), then the slave id, the
/// function code, the byte count and, for writes, the echo.
pub(crate) fn decode_response(
    slave: u8,
    request: &Request,
    frame: &[u8],
) -> Result<Response, FrameError> {
    check_envelope(slave, frame, 5)?;
    let function = frame[1];
    if function == request.function() | EXCEPTION_BIT {
        check_len(frame, 5)?;
        return Err(FrameError::Exception {
            function: request.function(),
            exception: Exception::from_code(frame[2]),
        });
    }
    if function != request.function() {
        return Err(FrameError::WrongFunction {
            expected: request.function(),
            got: function,
        });
    }
    match request {
        Request::ReadHolding { count, .. } | Request::ReadInput { count, .. } => {
            let expected = *count as usize * 2;
            let got = frame[2] as usize;
            if got != expected {
                return Err(FrameError::ByteCount { expected, got });
            }
            check_len(frame, 3 + got + 2)?;
            let regs = (0..*count as usize).map(|i| be(frame, 3 + 2 * i)).collect();
            Ok(if function == READ_HOLDING {
                Response::ReadHolding(regs)
            } else {
                Response::ReadInput(regs)
            })
        }
        Request::WriteSingle { addr, value } => {
            check_len(frame, 8)?;
            let got = [be(frame, 2), be(frame, 4)];
            if got != [*addr, *value] {
                return Err(FrameError::EchoMismatch {
                    expected: [*addr, *value],
                    got,
                });
            }
            Ok(Response::WriteSingle {
                addr: got[0],
                value: got[1],
            })
        }
        Request::WriteMultiple { addr, values } => {
            check_len(frame, 8)?;
            let got = [be(frame, 2), be(frame, 4)];
            let expected = [*addr, values.len() as u16];
            if got != expected {
                return Err(FrameError::EchoMismatch { expected, got });
            }
            Ok(Response::WriteMultiple {
                addr: got[0],
                count: got[1],
            })
        }
    }
}

fn check_len(frame: &[u8], len: usize) -> Result<(), FrameError> {
    if frame.len() == len {
        Ok(())
    } else {
        Err(FrameError::Length {
            expected: len,
            got: frame.len(),
        })
    }
}

// ---- slave side ----

/// What a slave makes of the bytes at the front of its input.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Incoming {
    /// Not a whole frame yet: wait for more bytes.
    Incomplete,
    /// A well-formed request of `len` bytes for `slave`.
    Request {
        slave: u8,
        request: Request,
        len: usize,
    },
    /// A frame of `len` bytes with a good CRC that the slave must refuse with
    /// `exception` (if addressed to it): an unknown function, a bad count.
    Refuse {
        slave: u8,
        function: u8,
        exception: Exception,
        len: usize,
    },
    /// `len` bytes that are no frame (bad CRC, or no way to find its end): dropped
    /// without a reply, as a real slave drops a corrupted frame.
    Garbage { len: usize, why: String },
}

/// Length of a request frame with a function code adrive does not serve, from the
/// spec's request layouts, so the slave can answer "illegal function" and stay in step.
fn other_request_len(buf: &[u8]) -> Option<Option<usize>> {
    let need = |n: usize| Some(if buf.len() >= n { Some(n) } else { None });
    let counted = |at: usize, fixed: usize| {
        Some(if buf.len() > at {
            Some(fixed + buf[at] as usize + 2)
        } else {
            None
        })
    };
    match buf[1] {
        0x01 | 0x02 | 0x05 => need(8),
        0x07 | 0x0B | 0x0C | 0x11 => need(4),
        0x0F => counted(6, 7),
        0x16 => need(10),
        0x17 => counted(10, 11),
        0x18 => need(6),
        _ => None,
    }
}

/// Find the request at the front of `buf`. Without the line's silence to mark frame
/// ends, the length comes from the function code and byte count; for a function code
/// whose layout is unknown the frame ends at the first position where the CRC checks.
pub fn decode_request(buf: &[u8]) -> Incoming {
    if buf.len() < 2 {
        return Incoming::Incomplete;
    }
    let (slave, function) = (buf[0], buf[1]);
    let len = match function {
        READ_HOLDING | READ_INPUT | WRITE_SINGLE => 8,
        WRITE_MULTIPLE => match buf.get(6) {
            Some(&n) => 7 + n as usize + 2,
            None => return Incoming::Incomplete,
        },
        _ => match other_request_len(buf) {
            Some(Some(n)) => n,
            Some(None) => return Incoming::Incomplete,
            None => {
                return match (4..=buf.len().min(MAX_FRAME)).find(|&n| crc_ok(&buf[..n])) {
                    Some(len) => Incoming::Refuse {
                        slave,
                        function,
                        exception: Exception::IllegalFunction,
                        len,
                    },
                    None if buf.len() >= MAX_FRAME => Incoming::Garbage {
                        len: 1,
                        why: format!("no frame end found after function {function:#04x}"),
                    },
                    None => Incoming::Incomplete,
                };
            }
        },
    };
    if buf.len() < len {
        return Incoming::Incomplete;
    }
    let frame = &buf[..len];
    if !crc_ok(frame) {
        return Incoming::Garbage {
            len,
            why: format!("bad CRC on a {len}-byte frame to slave {slave}"),
        };
    }
    let refuse = |exception| Incoming::Refuse {
        slave,
        function,
        exception,
        len,
    };
    let (a, b) = (be(frame, 2), be(frame, 4));
    let request = match function {
        READ_HOLDING | READ_INPUT => {
            if b == 0 || b > MAX_READ {
                return refuse(Exception::IllegalDataValue);
            }
            if function == READ_HOLDING {
                Request::ReadHolding { addr: a, count: b }
            } else {
                Request::ReadInput { addr: a, count: b }
            }
        }
        WRITE_SINGLE => Request::WriteSingle { addr: a, value: b },
        WRITE_MULTIPLE => {
            let bytes = frame[6] as usize;
            if b == 0 || b > MAX_WRITE || bytes != b as usize * 2 {
                return refuse(Exception::IllegalDataValue);
            }
            Request::WriteMultiple {
                addr: a,
                values: (0..b as usize).map(|i| be(frame, 7 + 2 * i)).collect(),
            }
        }
        _ => return refuse(Exception::IllegalFunction),
    };
    Incoming::Request {
        slave,
        request,
        len,
    }
}

/// The complete RTU frame of a normal response from `slave`.
pub fn encode_response(slave: u8, response: &Response) -> Vec<u8> {
    let mut f = vec![slave];
    match response {
        Response::ReadHolding(regs) | Response::ReadInput(regs) => {
            f.push(if matches!(response, Response::ReadHolding(_)) {
                READ_HOLDING
            } else {
                READ_INPUT
            });
            f.push((regs.len() * 2) as u8);
            for r in regs {
                f.extend_from_slice(&r.to_be_bytes());
            }
        }
        Response::WriteSingle { addr, value } => {
            f.push(WRITE_SINGLE);
            f.extend_from_slice(&addr.to_be_bytes());
            f.extend_from_slice(&value.to_be_bytes());
        }
        Response::WriteMultiple { addr, count } => {
            f.push(WRITE_MULTIPLE);
            f.extend_from_slice(&addr.to_be_bytes());
            f.extend_from_slice(&count.to_be_bytes());
        }
    }
    push_crc(&mut f);
    f
}

/// The complete RTU frame of an exception reply from `slave` to `function`.
pub(crate) fn encode_exception(slave: u8, function: u8, exception: Exception) -> Vec<u8> {
    let mut f = vec![slave, function | EXCEPTION_BIT, exception.code()];
    push_crc(&mut f);
    f
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn hex(s: &str) -> Vec<u8> {
        s.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    #[test]
    fn crc_matches_published_vectors() {
        // Read 10 holding registers from slave 1 at 0: the classic example frame.
        assert_eq!(crc16(&hex("01 03 00 00 00 0A")).to_le_bytes(), [0xC5, 0xCD]);
        // MODBUS over Serial Line V1.02, 6.2.2 (CRC generation): "02 07" -> CRC 0x1241,
        // sent 41 12.
        assert_eq!(crc16(&hex("02 07")), 0x1241);
        // Application Protocol spec example, read holding 108..110 of slave 17 (0x11).
        assert_eq!(
            encode_request(
                0x11,
                &Request::ReadHolding {
                    addr: 0x006B,
                    count: 3
                }
            ),
            hex("11 03 00 6B 00 03 76 87")[..]
        );
        // The catalogue check value of CRC-16/MODBUS.
        assert_eq!(crc16(b"123456789"), 0x4B37);
    }

    #[test]
    fn frame_gap_follows_the_serial_line_spec() {
        // 3.5 chars * 11 bits / 9600 baud = 4.0104 ms.
        let g = frame_gap(9600);
        assert!(
            g >= Duration::from_micros(4010) && g <= Duration::from_micros(4020),
            "{g:?}"
        );
        assert_eq!(frame_gap(115_200), Duration::from_micros(1750));
        assert_eq!(frame_gap(38_400), Duration::from_micros(1750));
        assert!(frame_gap(19_200) > Duration::from_micros(2000));
    }

    #[test]
    fn requests_encode_as_the_spec_shows() {
        assert_eq!(
            encode_request(
                0x11,
                &Request::WriteSingle {
                    addr: 0x0001,
                    value: 0x0003
                }
            ),
            hex("11 06 00 01 00 03 9A 9B")[..]
        );
        let f = encode_request(
            0x11,
            &Request::WriteMultiple {
                addr: 0x0001,
                values: vec![0x000A, 0x0102],
            },
        );
        assert_eq!(&f[..11], &*hex("11 10 00 01 00 02 04 00 0A 01 02"));
        assert!(crc_ok(&f));
        assert_eq!(
            encode_request(1, &Request::ReadInput { addr: 8, count: 1 })[..6],
            hex("01 04 00 08 00 01")[..]
        );
    }

    #[test]
    fn a_read_response_decodes_to_its_registers() {
        let req = Request::ReadHolding {
            addr: 0x006B,
            count: 3,
        };
        // Spec example response: 022B 0000 0064.
        let mut f = hex("11 03 06 02 2B 00 00 00 64");
        push_crc(&mut f);
        assert_eq!(response_len(&f[..3]), Ok(Some(f.len())));
        assert_eq!(
            decode_response(0x11, &req, &f),
            Ok(Response::ReadHolding(vec![0x022B, 0, 0x64]))
        );
    }

    #[test]
    fn exceptions_decode_to_their_names() {
        let req = Request::ReadInput { addr: 99, count: 1 };
        let f = encode_exception(1, READ_INPUT, Exception::IllegalDataAddress);
        assert_eq!(f[1], 0x84);
        assert_eq!(response_len(&f[..3]), Ok(Some(5)));
        let err = decode_response(1, &req, &f).unwrap_err();
        assert_eq!(
            err,
            FrameError::Exception {
                function: READ_INPUT,
                exception: Exception::IllegalDataAddress
            }
        );
        assert_eq!(err.to_string(), "illegal data address (function 0x04)");
        for code in 0..=0x0Bu8 {
            assert_eq!(Exception::from_code(code).code(), code);
        }
        assert_eq!(Exception::from_code(4).name(), "server device failure");
    }

    #[test]
    fn a_reply_from_another_slave_is_rejected() {
        let req = Request::ReadInput { addr: 0, count: 1 };
        let f = encode_response(2, &Response::ReadInput(vec![7]));
        assert_eq!(
            decode_response(1, &req, &f),
            Err(FrameError::WrongSlave {
                expected: 1,
                got: 2
            })
        );
    }

    #[test]
    fn a_reply_with_a_bad_crc_is_rejected() {
        let req = Request::ReadInput { addr: 0, count: 1 };
        let mut f = encode_response(1, &Response::ReadInput(vec![7]));
        f[4] ^= 0x01;
        assert!(matches!(
            decode_response(1, &req, &f),
            Err(FrameError::BadCrc { .. })
        ));
        // A flipped slave id is a CRC error too, never "another slave".
        let mut f = encode_response(1, &Response::ReadInput(vec![7]));
        f[0] = 2;
        assert!(matches!(
            decode_response(1, &req, &f),
            Err(FrameError::BadCrc { .. })
        ));
    }

    #[test]
    fn truncated_and_mismatched_replies_are_rejected() {
        let req = Request::ReadInput { addr: 0, count: 2 };
        let f = encode_response(1, &Response::ReadInput(vec![7, 8]));
        assert!(decode_response(1, &req, &f[..6]).is_err());
        assert!(matches!(
            decode_response(1, &req, &f[..3]),
            Err(FrameError::Truncated { .. })
        ));
        // One register where two were asked for.
        let short = encode_response(1, &Response::ReadInput(vec![7]));
        assert!(matches!(
            decode_response(1, &req, &short),
            Err(FrameError::ByteCount { .. })
        ));
        // A holding reply to an input read.
        let other = encode_response(1, &Response::ReadHolding(vec![7, 8]));
        assert!(matches!(
            decode_response(1, &req, &other),
            Err(FrameError::WrongFunction { .. })
        ));
        // A write echo that differs.
        let w = Request::WriteSingle { addr: 0, value: 5 };
        let echo = encode_response(1, &Response::WriteSingle { addr: 0, value: 6 });
        assert!(matches!(
            decode_response(1, &w, &echo),
            Err(FrameError::EchoMismatch { .. })
        ));
        assert_eq!(
            response_len(&[1, 0x2B, 0]),
            Err(FrameError::UnknownFunction(0x2B))
        );
        assert_eq!(response_len(&[1, 3]), Ok(None));
    }

    #[test]
    fn the_slave_finds_frame_ends_without_silence() {
        let a = encode_request(1, &Request::ReadHolding { addr: 0, count: 2 });
        let b = encode_request(
            1,
            &Request::WriteMultiple {
                addr: 4,
                values: vec![1, 2, 3],
            },
        );
        let mut buf = a.to_vec();
        buf.extend_from_slice(&b);
        for cut in 0..a.len() {
            assert_eq!(
                decode_request(&buf[..cut]),
                Incoming::Incomplete,
                "cut {cut}"
            );
        }
        assert_eq!(
            decode_request(&buf),
            Incoming::Request {
                slave: 1,
                request: Request::ReadHolding { addr: 0, count: 2 },
                len: 8
            }
        );
        for cut in 0..b.len() {
            assert_eq!(decode_request(&b[..cut]), Incoming::Incomplete, "cut {cut}");
        }
        assert_eq!(
            decode_request(&buf[8..]),
            Incoming::Request {
                slave: 1,
                request: Request::WriteMultiple {
                    addr: 4,
                    values: vec![1, 2, 3]
                },
                len: b.len()
            }
        );
    }

    #[test]
    fn the_slave_drops_a_frame_with_a_bad_crc() {
        let mut f = encode_request(1, &Request::ReadInput { addr: 0, count: 1 });
        f[7] ^= 0xFF;
        assert!(matches!(
            decode_request(&f),
            Incoming::Garbage { len: 8, .. }
        ));
    }

    #[test]
    fn the_slave_refuses_unknown_functions_and_bad_counts() {
        // Read coils (01): known layout, not served.
        let mut f = hex("01 01 00 00 00 08");
        push_crc(&mut f);
        assert_eq!(
            decode_request(&f),
            Incoming::Refuse {
                slave: 1,
                function: 1,
                exception: Exception::IllegalFunction,
                len: 8
            }
        );
        // A function with no layout known: the frame ends where the CRC checks.
        let mut f = hex("01 41 02 03");
        push_crc(&mut f);
        assert_eq!(decode_request(&f[..5]), Incoming::Incomplete);
        assert!(matches!(
            decode_request(&f),
            Incoming::Refuse {
                len: 6,
                exception: Exception::IllegalFunction,
                ..
            }
        ));
        // 126 registers is one more than a read may ask for.
        let f = encode_request(
            1,
            &Request::ReadHolding {
                addr: 0,
                count: 126,
            },
        );
        assert!(matches!(
            decode_request(&f),
            Incoming::Refuse {
                exception: Exception::IllegalDataValue,
                ..
            }
        ));
    }

    fn any_request() -> impl Strategy<Value = Request> {
        prop_oneof![
            (any::<u16>(), 1..=MAX_READ)
                .prop_map(|(addr, count)| Request::ReadHolding { addr, count }),
            (any::<u16>(), 1..=MAX_READ)
                .prop_map(|(addr, count)| Request::ReadInput { addr, count }),
            (any::<u16>(), any::<u16>())
                .prop_map(|(addr, value)| Request::WriteSingle { addr, value }),
            (
                any::<u16>(),
                proptest::collection::vec(any::<u16>(), 1..=MAX_WRITE as usize)
            )
                .prop_map(|(addr, values)| Request::WriteMultiple { addr, values }),
        ]
    }

    proptest! {
        #[test]
        fn requests_round_trip(slave in 1u8..=247, req in any_request(), tail in proptest::collection::vec(any::<u8>(), 0..8)) {
            let mut buf = encode_request(slave, &req).to_vec();
            let len = buf.len();
            prop_assert!(len <= MAX_FRAME);
            buf.extend_from_slice(&tail);
            prop_assert_eq!(decode_request(&buf), Incoming::Request { slave, request: req, len });
        }

        #[test]
        fn read_responses_round_trip(slave in 1u8..=247, regs in proptest::collection::vec(any::<u16>(), 1..=MAX_READ as usize)) {
            let req = Request::ReadInput { addr: 0, count: regs.len() as u16 };
            let f = encode_response(slave, &Response::ReadInput(regs.clone()));
            prop_assert_eq!(response_len(&f[..3]), Ok(Some(f.len())));
            prop_assert_eq!(decode_response(slave, &req, &f), Ok(Response::ReadInput(regs)));
        }

        #[test]
        fn any_single_bit_flip_is_caught(regs in proptest::collection::vec(any::<u16>(), 1..8), bit in 0usize..1000) {
            let req = Request::ReadHolding { addr: 0, count: regs.len() as u16 };
            let mut f = encode_response(1, &Response::ReadHolding(regs));
            let bit = bit % (f.len() * 8);
            f[bit / 8] ^= 1 << (bit % 8);
            prop_assert!(decode_response(1, &req, &f).is_err());
        }
    }
}
