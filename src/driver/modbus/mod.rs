//! The Modbus RTU driver: adrive as bus master to servo drives that speak Modbus, the
//! common tongue of industrial actuators. A [`ModbusMap`] from the vehicle file says
//! which register takes the set point (or a state's code) and which report each
//! reading; the driver turns a poll into as few register reads as the map allows and
//! a command into one register write. The framing itself lives in [`proto`]; the simulated slave that serves the
//! same maps is [`crate::sim::modbus`].

pub mod proto;

use self::proto::{FrameError, Request, Response};
use super::{read_some, send_request, Deadline, Driver, DriverError, Link};
use crate::config::protocol_map::{Block, Field, ModbusMap, RegisterKind};
use crate::config::ReadingKind;
use crate::value::{Command, Reading};
use std::time::{Duration, Instant};

pub use crate::config::protocol_map::to_register;

/// Host side of a Modbus RTU actuator.
pub struct ModbusDriver {
    map: ModbusMap,
    plan: Vec<Block>,
    slave: u8,
    gap: Duration,
    reply_timeout: Duration,
    /// When the line last went quiet (end of our request or of the last reply).
    quiet_since: Option<Instant>,
    /// A command's request that went out, and its deadline, while its reply is still
    /// to be read ([`Driver::send_command`] → [`Driver::finish_command`]).
    awaiting: Option<(Request, Deadline)>,
}

impl ModbusDriver {
    /// A driver for the slave laid out as `map`, on a line at `baud`, waiting up to
    /// `reply_timeout` for each reply.
    pub fn new(map: ModbusMap, baud: u32, reply_timeout: Duration) -> ModbusDriver {
        ModbusDriver {
            plan: map.read_plan(),
            slave: map.slave,
            map,
            gap: proto::frame_gap(baud),
            reply_timeout,
            quiet_since: None,
            awaiting: None,
        }
    }

    pub fn map(&self) -> &ModbusMap {
        &self.map
    }

    /// One request, one reply: wait out the inter-frame silence, send, read the reply
    /// frame by its own length, decode.
    fn transact(
        &mut self,
        link: &mut dyn Link,
        request: &Request,
    ) -> Result<Response, DriverError> {
        let deadline = self.send(link, request)?;
        self.receive(link, request, &deadline)
    }

    /// When the inter-frame silence after the last frame on the line is over.
    fn ready_at(&self) -> Option<Instant> {
        self.quiet_since.map(|t| t + self.gap)
    }

    /// Wait out the inter-frame silence, then send `request`; returns its deadline.
    fn send(&mut self, link: &mut dyn Link, request: &Request) -> Result<Deadline, DriverError> {
        if let Some(ready) = self.ready_at() {
            let now = Instant::now();
            if ready > now {
                std::thread::sleep(ready - now);
            }
        }
        let frame = proto::encode_request(self.slave, request);
        let sent = send_request(link, &frame, self.reply_timeout);
        self.quiet_since = Some(Instant::now());
        sent
    }

    /// Read and decode the reply to `request`, sent with `deadline`.
    fn receive(
        &mut self,
        link: &mut dyn Link,
        request: &Request,
        deadline: &Deadline,
    ) -> Result<Response, DriverError> {
        let reply = self.read_frame(link, deadline);
        self.quiet_since = Some(Instant::now());
        let reply = reply?;
        proto::decode_response(self.slave, request, &reply).map_err(|e| match e {
            FrameError::Exception { .. } => DriverError::Refused(e.to_string()),
            e => DriverError::Garbled(e.to_string()),
        })
    }

    /// Read one reply frame by its own length; it must be complete by `deadline`.
    fn read_frame(
        &mut self,
        link: &mut dyn Link,
        deadline: &Deadline,
    ) -> Result<proto::Frame, DriverError> {
        let mut buf = proto::Frame::new();
        let mut want = 3;
        let mut chunk = [0u8; proto::MAX_FRAME];
        while buf.len() < want {
            let room = (want - buf.len()).min(chunk.len());
            let n = match read_some(link, &mut chunk[..room], deadline) {
                Ok(n) => n,
                Err(DriverError::Timeout(_)) if !buf.is_empty() => {
                    return Err(DriverError::Garbled(
                        FrameError::Truncated {
                            needed: want,
                            got: buf.len(),
                        }
                        .to_string(),
                    ));
                }
                Err(e) => return Err(e),
            };
            buf.extend(chunk[..n].iter().copied());
            if buf.len() >= 3 && want == 3 {
                want = proto::response_len(&buf)
                    .map_err(|e| {
                        let _ = link.discard_input();
                        DriverError::Garbled(e.to_string())
                    })?
                    .unwrap_or(3);
                if want > proto::MAX_FRAME {
                    let _ = link.discard_input();
                    return Err(DriverError::Garbled(format!(
                        "a reply announcing {want} bytes, longer than a frame"
                    )));
                }
            }
        }
        Ok(buf)
    }
}

impl Driver for ModbusDriver {
    fn longest(&self) -> Duration {
        // A poll: one exchange per register block, each after the inter-frame silence.
        (self.gap + self.reply_timeout) * self.plan.len().max(1) as u32
    }

    fn poll(&mut self, link: &mut dyn Link) -> Result<Reading, DriverError> {
        let mut reading = Reading::default();
        for bi in 0..self.plan.len() {
            let block = &self.plan[bi];
            let count = block.fields.len() as u16;
            let request = match self.map.table {
                RegisterKind::Holding => Request::ReadHolding {
                    addr: block.start,
                    count,
                },
                RegisterKind::Input => Request::ReadInput {
                    addr: block.start,
                    count,
                },
            };
            let regs = match self.transact(link, &request)? {
                Response::ReadHolding(r) | Response::ReadInput(r) => r,
                other => {
                    return Err(DriverError::Garbled(format!(
                        "unexpected response {other:?}"
                    )))
                }
            };
            let block = &self.plan[bi];
            for (fi, raw) in block.fields.iter().zip(regs) {
                match &self.map.fields[*fi].1 {
                    Field::Status => reading.fault = raw & self.map.fault_mask,
                    Field::Reading { index, scale } => {
                        let v = match &self.map.kinds[*index] {
                            ReadingKind::Number => scale.value(raw),
                            ReadingKind::Flag => f64::from(u8::from(raw != 0)),
                            ReadingKind::States(s) => {
                                let state = if self.map.own_states[*index] {
                                    self.map.state_of_code(raw)
                                } else {
                                    (usize::from(raw) < s.len()).then_some(raw as u8)
                                };
                                state.ok_or_else(|| {
                                    DriverError::Garbled(format!(
                                        "unknown state code {raw} in register {}",
                                        self.map.fields[*fi].0
                                    ))
                                })? as f64
                            }
                        };
                        reading.set(*index, v);
                    }
                }
            }
        }
        Ok(reading)
    }

    fn command(&mut self, link: &mut dyn Link, command: Command) -> Result<(), DriverError> {
        self.send_command(link, command)?;
        self.finish_command(link)
    }

    fn sends_at_once(&self) -> bool {
        self.ready_at().is_none_or(|t| t <= Instant::now())
    }

    fn send_command(&mut self, link: &mut dyn Link, command: Command) -> Result<(), DriverError> {
        self.awaiting = None;
        let request = self.command_request(command)?;
        let deadline = self.send(link, &request)?;
        self.awaiting = Some((request, deadline));
        Ok(())
    }

    fn finish_command(&mut self, link: &mut dyn Link) -> Result<(), DriverError> {
        let (request, deadline) = self.awaiting.take().ok_or_else(|| {
            DriverError::Unsupported("a reply awaited with no command sent".into())
        })?;
        self.receive(link, &request, &deadline).map(|_| ())
    }
}

impl ModbusDriver {
    /// The register write that carries `command`.
    fn command_request(&self, command: Command) -> Result<Request, DriverError> {
        let (addr, value) = match command {
            Command::Control(c) => (
                self.map.control.ok_or_else(|| {
                    DriverError::Unsupported(format!("{c}: this device has no control register"))
                })?,
                c.code(),
            ),
            Command::State(i) => {
                let code = self.map.codes.get(i as usize).copied().ok_or_else(|| {
                    DriverError::Unsupported(format!("state #{i}: this device has no code for it"))
                })?;
                (self.target()?, code)
            }
            Command::Set(v) => {
                if !self.map.codes.is_empty() {
                    return Err(DriverError::Unsupported(format!(
                        "set point {v} sent to a state device"
                    )));
                }
                let raw = self.map.scale.raw(v).ok_or_else(|| {
                    DriverError::Unsupported(format!(
                        "{v} does not fit the target register (scale {}, offset {})",
                        self.map.scale.scale, self.map.scale.offset
                    ))
                })?;
                (self.target()?, raw)
            }
        };
        Ok(Request::WriteSingle { addr, value })
    }

    fn target(&self) -> Result<u16, DriverError> {
        self.map
            .target
            .ok_or_else(|| DriverError::Unsupported("this device takes no commands".into()))
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::proto::{encode_exception, encode_request, encode_response, Exception};
    use super::*;
    use crate::driver::mock::{rx, tx, MockLink, Step};

    use crate::config::protocol_map::{Scale, Wire};

    const T: Duration = Duration::from_millis(50);

    /// The register map of one of Alice's devices, as her vehicle file has it.
    pub(crate) fn alice(name: &str) -> ModbusMap {
        match crate::config::VehicleConfig::alice()
            .device(name)
            .unwrap()
            .wire
            .clone()
        {
            Wire::Modbus(m) => m,
            other => panic!("{other:?}"),
        }
    }

    fn steer() -> ModbusDriver {
        ModbusDriver::new(alice("steer"), 115_200, T)
    }

    #[test]
    fn the_alice_maps_poll_in_one_read() {
        for name in ["steer", "gas", "brake", "trans"] {
            assert_eq!(alice(name).read_plan().len(), 1, "{name}");
        }
    }

    fn map(registers: &str) -> Result<ModbusMap, String> {
        let text = format!(
            "[vehicle]\nname = \"t\"\n[[device]]\nname = \"d\"\nkind = \"setpoint\"\nrange = [0.0, 1.0]\nreadings = [\"position\", \"velocity\"]\ndriver = \"modbus\"\n[device.modbus]\nslave = 1\nregisters = {{ {registers} }}\n"
        );
        crate::config::parse(&text, "t.toml")
            .map(|mut v| match v.devices.remove(0).wire {
                Wire::Modbus(m) => m,
                other => panic!("{other:?}"),
            })
            .map_err(|e| e.to_string())
    }

    #[test]
    fn holes_split_the_read_plan() {
        let m = map("target = 0, position = 10, velocity = 11, status = 20").unwrap();
        let plan = m.read_plan();
        assert_eq!(plan.len(), 2);
        assert_eq!((plan[0].start, plan[0].fields.len()), (10, 2));
        assert_eq!((plan[1].start, plan[1].fields.len()), (20, 1));
    }

    #[test]
    fn scale_and_offset_convert_both_ways() {
        let mut m = Scale {
            scale: 0.5,
            offset: 10.0,
            signed: true,
        };
        assert_eq!(m.value((-4i16) as u16), 8.0);
        assert_eq!(m.raw(8.0), Some((-4i16) as u16));
        assert_eq!(m.raw(1e9), None);
        m.signed = false;
        assert_eq!(m.raw(9.0), None, "negative raw in an unsigned register");
        assert_eq!(m.value(0xFFFF), 65535.0 * 0.5 + 10.0);
    }

    #[test]
    fn a_register_map_loads_from_toml_and_rejects_typos() {
        let m = map("target = 0, position = 7, velocity = 8, table = \"holding\"").unwrap();
        assert_eq!(m.table, RegisterKind::Holding);
        let e = map("target = 0, position = 0, positon = 1").unwrap_err();
        assert!(
            e.contains("positon") && e.contains("position, velocity"),
            "{e}"
        );
        let e = map("target = 0, position = 0").unwrap_err();
        assert!(e.contains("reading velocity has no register"), "{e}");
        let e = map("position = 0, velocity = 1").unwrap_err();
        assert!(e.contains("target"), "{e}");
    }

    #[test]
    fn poll_reads_the_feedback_block_and_scales_it() {
        let req = encode_request(1, &Request::ReadInput { addr: 0, count: 3 });
        let reply = encode_response(
            1,
            &Response::ReadInput(vec![(-5000i16) as u16, 2500, 0x8001]),
        );
        let mut link = MockLink::new([tx(req), rx(reply)]);
        let r = steer().poll(&mut link).unwrap();
        assert_eq!(r.get(0), Some(-0.5), "position");
        assert_eq!(r.get(1), Some(0.25), "velocity");
        assert_eq!(r.fault, 0x0001, "the high status byte is not a fault");
        assert!(link.timeout.is_some_and(|t| t <= T), "{:?}", link.timeout);
    }

    #[test]
    fn a_set_point_is_one_write_single() {
        let req = encode_request(
            1,
            &Request::WriteSingle {
                addr: 0,
                value: 2500,
            },
        );
        let echo = encode_response(
            1,
            &Response::WriteSingle {
                addr: 0,
                value: 2500,
            },
        );
        let mut link = MockLink::new([tx(req), rx(echo)]);
        steer().command(&mut link, Command::Set(0.25)).unwrap();
    }

    /// The split command: the request frame, exactly, then the echo read and checked
    /// by the second half.
    #[test]
    fn a_set_point_splits_into_its_request_and_its_echo() {
        let mut d = steer();
        let write = Request::WriteSingle {
            addr: 0,
            value: 2500,
        };
        let echo = encode_response(
            1,
            &Response::WriteSingle {
                addr: 0,
                value: 2500,
            },
        );
        assert!(d.sends_at_once(), "nothing went over the line yet");
        let mut link = MockLink::new([tx(encode_request(1, &write))]);
        d.send_command(&mut link, Command::Set(0.25)).unwrap();
        link.done();
        let mut link = MockLink::new([rx(&echo)]);
        d.finish_command(&mut link).unwrap();
        drop(link);
        // An echo of another value is not an acknowledgement.
        let mut link = MockLink::new([tx(encode_request(1, &write))]);
        d.send_command(&mut link, Command::Set(0.25)).unwrap();
        drop(link);
        let wrong = encode_response(1, &Response::WriteSingle { addr: 0, value: 1 });
        let mut link = MockLink::new([rx(&wrong)]);
        assert!(matches!(
            d.finish_command(&mut link),
            Err(DriverError::Garbled(_))
        ));
    }

    /// Right after a frame the line owes the inter-frame silence: the driver would wait
    /// before writing, so it does not offer to write at once.
    #[test]
    fn a_request_does_not_go_at_once_inside_the_inter_frame_silence() {
        // At 1200 baud the silence is 32 ms.
        let mut d = ModbusDriver::new(alice("steer"), 1200, T);
        let write = Request::WriteSingle {
            addr: 0,
            value: 2500,
        };
        let mut link = MockLink::new([tx(encode_request(1, &write))]);
        d.send_command(&mut link, Command::Set(0.25)).unwrap();
        assert!(!d.sends_at_once());
        std::thread::sleep(proto::frame_gap(1200));
        assert!(d.sends_at_once());
        drop(link);
    }

    /// A command the device cannot take fails before a byte is written.
    #[test]
    fn an_unsupported_command_writes_nothing() {
        let mut d = steer();
        let mut link = MockLink::new([]);
        assert!(matches!(
            d.send_command(&mut link, Command::State(0)),
            Err(DriverError::Unsupported(_))
        ));
    }

    #[test]
    fn a_state_is_written_as_its_code() {
        let mut d = ModbusDriver::new(alice("trans"), 9600, T);
        let req = encode_request(4, &Request::WriteSingle { addr: 0, value: 3 });
        let echo = encode_response(4, &Response::WriteSingle { addr: 0, value: 3 });
        let mut link = MockLink::new([tx(req), rx(echo)]);
        d.command(&mut link, Command::State(3)).unwrap();
        drop(link);
        let mut link = MockLink::new([]);
        assert!(matches!(
            d.command(&mut link, Command::Set(1.0)),
            Err(DriverError::Unsupported(_))
        ));
        assert!(matches!(
            steer().command(&mut link, Command::State(0)),
            Err(DriverError::Unsupported(_))
        ));
        assert!(matches!(
            steer().command(&mut link, Command::Set(7.0)),
            Err(DriverError::Unsupported(_))
        ));
    }

    #[test]
    fn the_trans_reports_its_state() {
        let mut d = ModbusDriver::new(alice("trans"), 9600, T);
        let req = encode_request(4, &Request::ReadInput { addr: 0, count: 2 });
        let reply = encode_response(4, &Response::ReadInput(vec![1, 0]));
        let mut link = MockLink::new([tx(&req), rx(reply)]);
        assert_eq!(d.poll(&mut link).unwrap().get(0), Some(1.0), "reverse");
        let bad = encode_response(4, &Response::ReadInput(vec![9, 0]));
        let mut link = MockLink::new([tx(&req), rx(bad)]);
        assert!(matches!(d.poll(&mut link), Err(DriverError::Garbled(_))));
    }

    #[test]
    fn an_exception_is_a_refusal_by_name() {
        let req = encode_request(
            1,
            &Request::WriteSingle {
                addr: 0,
                value: 100,
            },
        );
        let exc = encode_exception(1, proto::WRITE_SINGLE, Exception::ServerDeviceFailure);
        let mut link = MockLink::new([tx(req), rx(exc)]);
        match steer().command(&mut link, Command::Set(0.01)) {
            Err(DriverError::Refused(why)) => {
                assert!(why.contains("server device failure"), "{why}")
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_reply_from_another_slave_or_with_a_bad_crc_is_garbled() {
        let req = encode_request(1, &Request::ReadInput { addr: 0, count: 3 });
        let other = encode_response(9, &Response::ReadInput(vec![0, 0, 0]));
        let mut link = MockLink::new([tx(&req), rx(other)]);
        match steer().poll(&mut link) {
            Err(DriverError::Garbled(why)) => assert!(why.contains("slave 9"), "{why}"),
            other => panic!("{other:?}"),
        }
        let mut bad = encode_response(1, &Response::ReadInput(vec![0, 0, 0]));
        bad[5] ^= 0x40;
        let mut link = MockLink::new([tx(&req), rx(bad)]);
        match steer().poll(&mut link) {
            Err(DriverError::Garbled(why)) => assert!(why.contains("CRC"), "{why}"),
            other => panic!("{other:?}"),
        }
    }

    /// The echo there when the command's thread comes to read it after the deadline (a
    /// loaded machine): the device answered in time, and the frame — read by its
    /// length, in more than one read — is taken.
    #[test]
    fn an_echo_there_when_a_late_thread_reads_it_is_taken() {
        let mut d = steer();
        let write = Request::WriteSingle {
            addr: 0,
            value: 2500,
        };
        let mut link = MockLink::new([tx(encode_request(1, &write))]);
        d.send_command(&mut link, Command::Set(0.25)).unwrap();
        drop(link);
        std::thread::sleep(T + Duration::from_millis(10));
        let echo = encode_response(
            1,
            &Response::WriteSingle {
                addr: 0,
                value: 2500,
            },
        );
        let mut link = MockLink::new([rx(&echo)]);
        let r = d.finish_command(&mut link);
        assert!(r.is_ok(), "{r:?}");
        assert_eq!(
            link.timeout,
            Some(Duration::ZERO),
            "a late look never waits"
        );
    }

    #[test]
    fn silence_is_a_timeout_and_a_cut_reply_is_garbled() {
        let req = encode_request(1, &Request::ReadInput { addr: 0, count: 3 });
        let mut link = MockLink::new([tx(&req), Step::Silence]);
        assert!(matches!(steer().poll(&mut link), Err(DriverError::Timeout(t)) if t == T));
        let reply = encode_response(1, &Response::ReadInput(vec![0, 0, 0]));
        let mut link = MockLink::new([tx(&req), rx(&reply[..6]), Step::Silence]);
        match steer().poll(&mut link) {
            Err(DriverError::Garbled(why)) => assert!(why.contains("truncated"), "{why}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn frames_are_separated_by_the_inter_frame_silence() {
        // At 1200 baud, 3.5 characters of 11 bits take 32 ms.
        let mut d = ModbusDriver::new(alice("gas"), 1200, T);
        let req = encode_request(2, &Request::ReadInput { addr: 0, count: 2 });
        let reply = encode_response(2, &Response::ReadInput(vec![0, 0]));
        let mut link = MockLink::new([tx(&req), rx(&reply), tx(&req), rx(&reply)]);
        d.poll(&mut link).unwrap();
        let first_done = Instant::now();
        d.poll(&mut link).unwrap();
        assert!(first_done.elapsed() >= proto::frame_gap(1200));
    }
}
