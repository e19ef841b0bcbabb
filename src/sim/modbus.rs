//! A simulated Modbus RTU slave: serves functions 03, 04, 06 and 16 over a
//! [`ModbusMap`] from a live [`Plant`], so `adrive --sim` exercises the same driver
//! code as the field, and any Modbus master (mbpoll, pymodbus) pointed at the
//! pseudo-terminal sees an ordinary servo drive.
//!
//! Reads of feedback registers come from `plant.reading()`; the target register reads
//! back the last set point written. A write to the target becomes `plant.command(..)`.
//! Errors answer as a real slave does: an unmapped address is exception 02, a value
//! the map cannot express (an unknown gear code) is 03, a command the plant refuses
//! is 04, an unknown function is 01. A frame with a bad CRC or for another slave id is
//! dropped without a word; a broadcast (id 0) write is applied, never answered.

use super::device::{Plant, Reply, Responder};
use crate::config::protocol_map::{Field, ModbusMap, RegisterKind};
use crate::config::ReadingKind;
use crate::driver::modbus::proto::{self, Exception, Incoming, Request, Response};
use crate::value::{Command, Reading};

/// The device side of a Modbus device.
pub(crate) struct ModbusSlave {
    id: u8,
    map: ModbusMap,
    /// Raw contents of the target register: the last set point or state code written.
    target: u16,
    /// Frames dropped for a bad CRC (for the simulator's statistics).
    pub dropped: u64,
}

impl ModbusSlave {
    pub(crate) fn new(map: ModbusMap) -> ModbusSlave {
        ModbusSlave {
            id: map.slave,
            map,
            target: 0,
            dropped: 0,
        }
    }

    fn read(
        &self,
        kind: RegisterKind,
        addr: u16,
        count: u16,
        now: &Reading,
    ) -> Result<Vec<u16>, Exception> {
        (addr as u32..addr as u32 + count as u32)
            .map(|a| {
                let a = u16::try_from(a).map_err(|_| Exception::IllegalDataAddress)?;
                if kind == RegisterKind::Holding && Some(a) == self.map.target {
                    return Ok(self.target);
                }
                if kind != self.map.table {
                    return Err(Exception::IllegalDataAddress);
                }
                let field = self.map.field_at(a).ok_or(Exception::IllegalDataAddress)?;
                Ok(self.encode(field, now))
            })
            .collect()
    }

    /// A feedback field as its register holds it; a value the plant does not know
    /// reads as 0.
    fn encode(&self, field: &Field, now: &Reading) -> u16 {
        match field {
            Field::Status => now.fault,
            Field::Reading { index, scale } => {
                let Some(v) = now.get(*index) else {
                    return 0;
                };
                match &self.map.kinds[*index] {
                    ReadingKind::Number => scale.raw_clamped(v),
                    ReadingKind::Flag => u16::from(v != 0.0),
                    ReadingKind::States(_) if self.map.own_states[*index] => {
                        self.map.codes.get(v as usize).copied().unwrap_or(0)
                    }
                    ReadingKind::States(_) => v as u16,
                }
            }
        }
    }

    fn write(&mut self, addr: u16, raw: u16, plant: &mut dyn Plant) -> Result<(), Exception> {
        if Some(addr) == self.map.control && Some(addr) != self.map.target {
            let c = crate::value::Control::from_code(raw).ok_or(Exception::IllegalDataValue)?;
            return plant
                .command(Command::Control(c))
                .map_err(|_| Exception::ServerDeviceFailure);
        }
        if Some(addr) != self.map.target {
            return Err(Exception::IllegalDataAddress);
        }
        let command = if self.map.codes.is_empty() {
            Command::Set(self.map.scale.value(raw))
        } else {
            Command::State(
                self.map
                    .state_of_code(raw)
                    .ok_or(Exception::IllegalDataValue)?,
            )
        };
        plant
            .command(command)
            .map_err(|_| Exception::ServerDeviceFailure)?;
        self.target = raw;
        Ok(())
    }

    fn serve(&mut self, request: &Request, plant: &mut dyn Plant) -> Result<Response, Exception> {
        match request {
            Request::ReadHolding { addr, count } => {
                let now = plant.reading();
                self.read(RegisterKind::Holding, *addr, *count, &now)
                    .map(Response::ReadHolding)
            }
            Request::ReadInput { addr, count } => {
                let now = plant.reading();
                self.read(RegisterKind::Input, *addr, *count, &now)
                    .map(Response::ReadInput)
            }
            Request::WriteSingle { addr, value } => {
                self.write(*addr, *value, plant)?;
                Ok(Response::WriteSingle {
                    addr: *addr,
                    value: *value,
                })
            }
            Request::WriteMultiple { addr, values } => {
                // Only the target is writable, so only a one-register write can succeed.
                if values.len() != 1 {
                    return Err(Exception::IllegalDataAddress);
                }
                self.write(*addr, values[0], plant)?;
                Ok(Response::WriteMultiple {
                    addr: *addr,
                    count: 1,
                })
            }
        }
    }
}

impl Responder for ModbusSlave {
    fn respond(&mut self, input: &[u8], plant: &mut dyn Plant) -> Option<Reply> {
        let done = |consumed: usize, bytes: Vec<u8>| {
            Some(Reply {
                consumed,
                bytes,
                ..Reply::default()
            })
        };
        match proto::decode_request(input) {
            Incoming::Incomplete => None,
            Incoming::Garbage { len, .. } => {
                self.dropped += 1;
                done(len, Vec::new())
            }
            Incoming::Refuse {
                slave,
                function,
                exception,
                len,
            } => {
                if slave == self.id {
                    done(len, proto::encode_exception(self.id, function, exception))
                } else {
                    done(len, Vec::new())
                }
            }
            Incoming::Request {
                slave,
                request,
                len,
            } => {
                let broadcast = slave == proto::BROADCAST
                    && matches!(
                        request,
                        Request::WriteSingle { .. } | Request::WriteMultiple { .. }
                    );
                if broadcast {
                    let _ = self.serve(&request, plant);
                    return done(len, Vec::new());
                }
                if slave != self.id {
                    return done(len, Vec::new());
                }
                let bytes = match self.serve(&request, plant) {
                    Ok(response) => proto::encode_response(self.id, &response),
                    Err(e) => proto::encode_exception(self.id, request.function(), e),
                };
                done(len, bytes)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::driver::modbus::proto::{decode_response, encode_request, FrameError};
    use crate::driver::modbus::tests::alice;
    use crate::driver::modbus::ModbusDriver;
    use crate::driver::Driver;
    use crate::sim::test_serve::{serve_pty, TestPlant};
    use std::time::Duration;

    /// Alice's brake: position 0.5, pressure 25 bar, a fault bit and an info bit.
    fn brake() -> (ModbusSlave, TestPlant) {
        let mut reading = Reading::default();
        reading.set(0, 0.5);
        reading.set(1, 25.0);
        reading.fault = 0x0102;
        let plant = TestPlant {
            reading,
            ..TestPlant::default()
        };
        (ModbusSlave::new(alice("brake")), plant)
    }

    fn ask(
        slave: &mut ModbusSlave,
        plant: &mut TestPlant,
        id: u8,
        req: &Request,
    ) -> Result<Response, FrameError> {
        let frame = encode_request(id, req);
        let reply = slave.respond(&frame, plant).expect("a whole frame");
        assert_eq!(reply.consumed, frame.len());
        decode_response(id, req, &reply.bytes)
    }

    #[test]
    fn reads_come_from_the_plant() {
        let (mut s, mut p) = brake();
        let r = ask(&mut s, &mut p, 3, &Request::ReadInput { addr: 0, count: 3 });
        assert_eq!(r, Ok(Response::ReadInput(vec![5000, 2500, 0x0102])));
    }

    #[test]
    fn a_write_to_the_target_commands_the_plant_and_reads_back() {
        let (mut s, mut p) = brake();
        let w = Request::WriteSingle {
            addr: 0,
            value: 7500,
        };
        assert_eq!(
            ask(&mut s, &mut p, 3, &w),
            Ok(Response::WriteSingle {
                addr: 0,
                value: 7500
            })
        );
        assert_eq!(p.commands, vec![Command::Set(0.75)]);
        let r = ask(
            &mut s,
            &mut p,
            3,
            &Request::ReadHolding { addr: 0, count: 1 },
        );
        assert_eq!(r, Ok(Response::ReadHolding(vec![7500])));
        let w16 = Request::WriteMultiple {
            addr: 0,
            values: vec![100],
        };
        assert_eq!(
            ask(&mut s, &mut p, 3, &w16),
            Ok(Response::WriteMultiple { addr: 0, count: 1 })
        );
        assert_eq!(p.commands.last(), Some(&Command::Set(0.01)));
    }

    fn exception_of(r: Result<Response, FrameError>) -> Exception {
        match r {
            Err(FrameError::Exception { exception, .. }) => exception,
            other => panic!("expected an exception, got {other:?}"),
        }
    }

    #[test]
    fn errors_answer_with_the_right_exception() {
        let (mut s, mut p) = brake();
        let r = ask(&mut s, &mut p, 3, &Request::ReadInput { addr: 2, count: 2 });
        assert_eq!(exception_of(r), Exception::IllegalDataAddress);
        let r = ask(
            &mut s,
            &mut p,
            3,
            &Request::WriteSingle { addr: 1, value: 0 },
        );
        assert_eq!(exception_of(r), Exception::IllegalDataAddress);
        p.refuse = Some("brake disabled".into());
        let r = ask(
            &mut s,
            &mut p,
            3,
            &Request::WriteSingle { addr: 0, value: 1 },
        );
        assert_eq!(exception_of(r), Exception::ServerDeviceFailure);
        assert!(p.commands.is_empty());
        // Read coils: a function this slave does not serve.
        let mut coils = vec![3, 0x01, 0, 0, 0, 8];
        proto::push_crc(&mut coils);
        let reply = s.respond(&coils, &mut p).unwrap();
        assert_eq!(reply.consumed, 8);
        assert_eq!(&reply.bytes[..3], &[3, 0x81, 0x01]);
    }

    #[test]
    fn an_unknown_state_code_is_an_illegal_value() {
        let mut s = ModbusSlave::new(alice("trans"));
        let mut p = TestPlant::default();
        let r = ask(
            &mut s,
            &mut p,
            4,
            &Request::WriteSingle { addr: 0, value: 9 },
        );
        assert_eq!(exception_of(r), Exception::IllegalDataValue);
        let r = ask(
            &mut s,
            &mut p,
            4,
            &Request::WriteSingle { addr: 0, value: 1 },
        );
        assert!(r.is_ok());
        assert_eq!(p.commands, vec![Command::State(1)], "reverse");
    }

    #[test]
    fn frames_for_other_slaves_and_bad_crcs_are_consumed_in_silence() {
        let (mut s, mut p) = brake();
        let other = encode_request(7, &Request::WriteSingle { addr: 0, value: 1 });
        let mut bad = encode_request(3, &Request::WriteSingle { addr: 0, value: 1 });
        bad[5] ^= 1;
        let good = encode_request(3, &Request::ReadInput { addr: 0, count: 1 });
        let mut input = [other.clone(), bad.clone(), good.clone()].concat();
        let mut replies = Vec::new();
        while let Some(reply) = s.respond(&input, &mut p) {
            input.drain(..reply.consumed);
            replies.push(reply.bytes);
        }
        assert!(input.is_empty());
        assert_eq!(replies.len(), 3);
        assert!(replies[0].is_empty() && replies[1].is_empty());
        assert!(!replies[2].is_empty());
        assert!(p.commands.is_empty(), "neither frame may reach the plant");
        assert_eq!(s.dropped, 1);
    }

    #[test]
    fn a_broadcast_write_is_applied_without_a_reply() {
        let (mut s, mut p) = brake();
        let f = encode_request(
            0,
            &Request::WriteSingle {
                addr: 0,
                value: 10000,
            },
        );
        let reply = s.respond(&f, &mut p).unwrap();
        assert!(reply.bytes.is_empty());
        assert_eq!(p.commands, vec![Command::Set(1.0)]);
    }

    #[test]
    fn the_driver_and_the_slave_agree_over_a_pseudo_terminal() {
        let (s, p) = brake();
        let (server, mut link) = serve_pty(s, p);
        let mut d = ModbusDriver::new(alice("brake"), 115_200, Duration::from_secs(2));
        let r = d.poll(&mut link).unwrap();
        assert_eq!(r.get(0), Some(0.5), "position");
        assert_eq!(r.get(1), Some(25.0), "pressure");
        assert_eq!(r.fault, 0x0002);
        d.command(&mut link, Command::Set(0.3)).unwrap();
        // Same slave id, a map the device does not have: its feedback is unmapped.
        let mut wrong = alice("brake");
        wrong.fields[0].0 = 10;
        let mut wrong = ModbusDriver::new(wrong, 115_200, Duration::from_secs(2));
        match wrong.poll(&mut link) {
            Err(crate::driver::DriverError::Refused(why)) => {
                assert!(why.contains("illegal data address"), "{why}")
            }
            other => panic!("{other:?}"),
        }
        let plant = server.stop();
        assert_eq!(plant.commands, vec![Command::Set(0.3)]);
    }
}
