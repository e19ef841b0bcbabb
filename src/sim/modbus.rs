//! A simulated Modbus RTU slave: serves functions 03, 04, 06 and 16 over a
//! [`RegisterMap`] from a live [`Plant`], so `adrive --sim` exercises the same driver
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
use crate::driver::modbus::proto::{self, Exception, Incoming, Request, Response};
use crate::driver::modbus::{to_register, Field, RegisterKind, RegisterMap};
use crate::value::{Command, Reading};

/// The device side of a Modbus actuator.
pub struct ModbusSlave {
    id: u8,
    map: RegisterMap,
    /// Raw contents of the target register: the last set point written.
    target: u16,
    /// Frames dropped for a bad CRC (for the simulator's statistics).
    pub dropped: u64,
}

impl ModbusSlave {
    pub fn new(id: u8, map: RegisterMap) -> ModbusSlave {
        ModbusSlave {
            id,
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
                if kind == RegisterKind::Holding && a == self.map.target {
                    return Ok(self.target);
                }
                if kind != self.map.position_kind {
                    return Err(Exception::IllegalDataAddress);
                }
                let field = self.map.field_at(a).ok_or(Exception::IllegalDataAddress)?;
                Ok(self.encode(field, now))
            })
            .collect()
    }

    /// A feedback field as its register holds it; a value the plant does not know
    /// reads as 0.
    fn encode(&self, field: Field, now: &Reading) -> u16 {
        let m = &self.map;
        let fit = |x: f64| {
            let bound = if m.signed {
                x.clamp(i16::MIN as f64, i16::MAX as f64)
            } else {
                x.clamp(0.0, u16::MAX as f64)
            };
            to_register(bound, m.signed).unwrap_or(0)
        };
        match field {
            Field::Position => now.position.map_or(0, |v| fit((v - m.offset) / m.scale)),
            Field::Velocity => now.velocity.map_or(0, |v| fit(v / m.scale)),
            Field::Pressure => now
                .pressure
                .map_or(0, |p| fit(p / m.pressure_scale.unwrap_or(m.scale))),
            Field::Gear => now.gear.map_or(0, |g| g.code()),
            Field::Status => now.fault,
        }
    }

    fn write(&mut self, addr: u16, raw: u16, plant: &mut dyn Plant) -> Result<(), Exception> {
        if Some(addr) == self.map.control && addr != self.map.target {
            let c = crate::value::Control::from_code(raw).ok_or(Exception::IllegalDataValue)?;
            return plant
                .command(Command::Control(c))
                .map_err(|_| Exception::ServerDeviceFailure);
        }
        if addr != self.map.target {
            return Err(Exception::IllegalDataAddress);
        }
        let command = if self.map.is_gearbox() {
            Command::Gear(crate::value::Gear::from_code(raw).ok_or(Exception::IllegalDataValue)?)
        } else {
            Command::Set(self.map.value(raw))
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
    use crate::driver::modbus::{alice_map, ModbusDriver};
    use crate::driver::Driver;
    use crate::sim::test_serve::{serve_pty, TestPlant};
    use crate::value::{Gear, Role};
    use std::time::Duration;

    fn brake() -> (ModbusSlave, TestPlant) {
        let plant = TestPlant {
            reading: Reading {
                position: Some(0.5),
                pressure: Some(0.25),
                fault: 0x0102,
                ..Reading::default()
            },
            ..TestPlant::default()
        };
        (ModbusSlave::new(3, alice_map(Role::Brake).unwrap()), plant)
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
    fn an_unknown_gear_code_is_an_illegal_value() {
        let mut s = ModbusSlave::new(4, alice_map(Role::Trans).unwrap());
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
        assert_eq!(p.commands, vec![Command::Gear(Gear::Reverse)]);
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
        let mut d = ModbusDriver::new(
            alice_map(Role::Brake).unwrap(),
            3,
            115_200,
            Duration::from_secs(2),
        );
        let r = d.poll(&mut link).unwrap();
        assert_eq!(r.position, Some(0.5));
        assert_eq!(r.pressure, Some(0.25));
        assert_eq!(r.fault, 0x0002);
        d.command(&mut link, Command::Set(0.3)).unwrap();
        // Same slave id, a map the device does not have: its feedback is unmapped.
        let mut wrong = alice_map(Role::Brake).unwrap();
        wrong.position = Some(10);
        let mut wrong = ModbusDriver::new(wrong, 3, 115_200, Duration::from_secs(2));
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
