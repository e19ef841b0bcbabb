//! The Modbus RTU driver: adrive as bus master to servo drives that speak Modbus, the
//! common tongue of industrial actuators. A [`RegisterMap`] from the vehicle file says
//! which register takes the set point and which report the state; the driver turns a
//! poll into as few register reads as the map allows and a command into one register
//! write. The framing itself lives in [`proto`]; the simulated slave that serves the
//! same maps is [`crate::sim::modbus`].

pub mod proto;

use self::proto::{FrameError, Request, Response};
use super::{read_some, send_request, Deadline, Driver, DriverError, Link};
use crate::value::{Command, Gear, Reading, Role};
use serde::Deserialize;
use std::time::{Duration, Instant};

/// The register table a register lives in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RegisterKind {
    /// Read/write registers (function 03 to read); "4xxxx" in data sheets.
    Holding,
    /// Read-only registers (function 04); "3xxxx" in data sheets.
    #[default]
    Input,
}

/// Where a Modbus actuator keeps its set point and its state, and how register units
/// convert to adrive's value domain. Addresses are the 0-based addresses that go on the
/// wire: data sheet reference 40001 is holding register 0, 30001 is input register 0.
///
/// In the vehicle TOML, for example:
/// ```toml
/// [steer.registers]
/// target = 0          # 40001
/// position = 0        # 30001
/// velocity = 1        # 30002
/// status = 2          # 30003
/// fault_mask = 0x00FF
/// scale = 0.0001
/// signed = true
/// ```
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegisterMap {
    /// Holding register that takes the set point (or, on a transmission, the gear code).
    pub target: u16,
    /// Register that reports the position.
    #[serde(default)]
    pub position: Option<u16>,
    /// The table the feedback registers (position, velocity, pressure, gear, status)
    /// are read from.
    #[serde(default)]
    pub position_kind: RegisterKind,
    /// Register that reports the velocity, in register units per second.
    #[serde(default)]
    pub velocity: Option<u16>,
    /// Register that reports the (brake) pressure.
    #[serde(default)]
    pub pressure: Option<u16>,
    /// Register that reports the gear as a code (0 park, 1 reverse, 2 neutral, 3
    /// drive). Its presence makes the device a transmission: it takes gears, not set
    /// points.
    #[serde(default)]
    pub gear: Option<u16>,
    /// Holding register of the drive's control word: 0 disable, 1 enable, 3 home,
    /// 4 run the starter (see [`crate::value::Control::code`]).
    #[serde(default)]
    pub control: Option<u16>,
    /// Status word register; its bits under `fault_mask` are the device's faults.
    #[serde(default)]
    pub status: Option<u16>,
    #[serde(default = "all_bits")]
    pub fault_mask: u16,
    /// value = raw * scale + offset, for the target and the position.
    #[serde(default = "one")]
    pub scale: f64,
    #[serde(default)]
    pub offset: f64,
    /// pressure = raw * pressure_scale; defaults to `scale`.
    #[serde(default)]
    pub pressure_scale: Option<f64>,
    /// Registers hold i16 (true) or u16 (false).
    #[serde(default)]
    pub signed: bool,
}

fn all_bits() -> u16 {
    0xFFFF
}

fn one() -> f64 {
    1.0
}

/// One feedback register and what it means.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Field {
    Position,
    Velocity,
    Pressure,
    Gear,
    Status,
}

/// A run of contiguous registers read in one transaction.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Block {
    pub start: u16,
    pub fields: Vec<Field>,
}

impl RegisterMap {
    /// A map with only a target register; the rest is filled in by the caller.
    pub fn new(target: u16) -> RegisterMap {
        RegisterMap {
            target,
            position: None,
            position_kind: RegisterKind::Input,
            velocity: None,
            pressure: None,
            gear: None,
            control: None,
            status: None,
            fault_mask: 0xFFFF,
            scale: 1.0,
            offset: 0.0,
            pressure_scale: None,
            signed: false,
        }
    }

    /// True for a transmission: the target takes a gear code.
    pub fn is_gearbox(&self) -> bool {
        self.gear.is_some()
    }

    /// The mapped feedback registers, by address.
    pub fn feedback(&self) -> Vec<(u16, Field)> {
        let mut regs: Vec<(u16, Field)> = [
            (self.position, Field::Position),
            (self.velocity, Field::Velocity),
            (self.pressure, Field::Pressure),
            (self.gear, Field::Gear),
            (self.status, Field::Status),
        ]
        .into_iter()
        .filter_map(|(addr, f)| addr.map(|a| (a, f)))
        .collect();
        regs.sort_by_key(|(a, _)| *a);
        regs
    }

    /// The feedback register at `addr`, if any.
    pub fn field_at(&self, addr: u16) -> Option<Field> {
        self.feedback()
            .into_iter()
            .find(|(a, _)| *a == addr)
            .map(|(_, f)| f)
    }

    /// The reads a poll makes: each run of adjacent feedback registers is one read
    /// (a device may refuse a read that spans an unmapped hole, so holes split runs).
    pub fn read_plan(&self) -> Vec<Block> {
        let mut blocks: Vec<Block> = Vec::new();
        for (addr, field) in self.feedback() {
            match blocks.last_mut() {
                Some(b)
                    if b.start as u32 + b.fields.len() as u32 == addr as u32
                        && b.fields.len() < proto::MAX_READ as usize =>
                {
                    b.fields.push(field)
                }
                Some(b) if b.start as u32 + b.fields.len() as u32 > addr as u32 => {} // same address twice
                _ => blocks.push(Block {
                    start: addr,
                    fields: vec![field],
                }),
            }
        }
        blocks
    }

    /// A register's raw contents as a number, by `signed`.
    pub fn number(&self, raw: u16) -> f64 {
        if self.signed {
            raw as i16 as f64
        } else {
            raw as f64
        }
    }

    /// value = raw * scale + offset.
    pub fn value(&self, raw: u16) -> f64 {
        self.number(raw) * self.scale + self.offset
    }

    /// raw = round((value - offset) / scale), or `None` when that does not fit the
    /// register.
    pub fn raw(&self, value: f64) -> Option<u16> {
        to_register((value - self.offset) / self.scale, self.signed)
    }

    /// pressure = raw * pressure_scale (default `scale`).
    pub fn pressure_value(&self, raw: u16) -> f64 {
        self.number(raw) * self.pressure_scale.unwrap_or(self.scale)
    }

    /// velocity = raw * scale (units per second; no offset).
    pub fn velocity_value(&self, raw: u16) -> f64 {
        self.number(raw) * self.scale
    }
}

/// `x` rounded into a register, or `None` when it does not fit.
pub fn to_register(x: f64, signed: bool) -> Option<u16> {
    let x = x.round();
    if !x.is_finite() {
        return None;
    }
    if signed {
        (i16::MIN as f64..=i16::MAX as f64)
            .contains(&x)
            .then_some(x as i16 as u16)
    } else {
        (0.0..=u16::MAX as f64).contains(&x).then_some(x as u16)
    }
}

/// Slave id of each Modbus device of the simulated Alice. Each has its own port, but
/// distinct ids let them share one RS-485 bus as well.
pub fn alice_slave_id(role: Role) -> Option<u8> {
    match role {
        Role::Steer => Some(1),
        Role::Gas => Some(2),
        Role::Brake => Some(3),
        Role::Trans => Some(4),
        _ => None,
    }
}

/// The register maps of the simulated Alice, laid out like a small servo drive's:
/// the set point in holding register 40001, the feedback contiguous from input register
/// 30001 so that one read fetches it all. Status bits 0–7 are faults
/// (`fault_mask = 0x00FF`); the high byte is informational.
///
/// | device | slave | target (holding) | feedback (input, one read) | units (value = raw × scale) |
/// |--------|-------|------------------|----------------------------|-----------------------------|
/// | steer  | 1     | 40001 (0): set point, i16 | 30001 (0) position i16, 30002 (1) velocity i16 per s, 30003 (2) status | scale 0.0001: ±10000 = ±1 |
/// | gas    | 2     | 40001 (0): set point, u16 | 30001 (0) position, 30002 (1) status | scale 0.0001: 10000 = 1 |
/// | brake  | 3     | 40001 (0): set point, u16 | 30001 (0) position, 30002 (1) pressure, 30003 (2) status | scale 0.0001; pressure 10000 = 1 |
/// | trans  | 4     | 40001 (0): gear code | 30001 (0) gear code, 30002 (1) status | 0 park, 1 reverse, 2 neutral, 3 drive |
pub fn alice_map(role: Role) -> Option<RegisterMap> {
    let mut m = RegisterMap::new(0);
    m.position_kind = RegisterKind::Input;
    m.fault_mask = 0x00FF;
    match role {
        Role::Steer => {
            m.position = Some(0);
            m.velocity = Some(1);
            m.status = Some(2);
            m.scale = 1e-4;
            m.signed = true;
        }
        Role::Gas => {
            m.position = Some(0);
            m.status = Some(1);
            m.scale = 1e-4;
        }
        Role::Brake => {
            m.position = Some(0);
            m.pressure = Some(1);
            m.status = Some(2);
            m.scale = 1e-4;
        }
        Role::Trans => {
            m.gear = Some(0);
            m.status = Some(1);
        }
        Role::Estop | Role::Obd => return None,
    }
    Some(m)
}

/// Host side of a Modbus RTU actuator.
pub struct ModbusDriver {
    map: RegisterMap,
    plan: Vec<Block>,
    slave: u8,
    gap: Duration,
    reply_timeout: Duration,
    /// When the line last went quiet (end of our request or of the last reply).
    quiet_since: Option<Instant>,
}

impl ModbusDriver {
    /// A driver for slave `slave` laid out as `map`, on a line at `baud`, waiting up to
    /// `reply_timeout` for each reply.
    pub fn new(map: RegisterMap, slave: u8, baud: u32, reply_timeout: Duration) -> ModbusDriver {
        ModbusDriver {
            plan: map.read_plan(),
            map,
            slave,
            gap: proto::frame_gap(baud),
            reply_timeout,
            quiet_since: None,
        }
    }

    pub fn map(&self) -> &RegisterMap {
        &self.map
    }

    /// One request, one reply: wait out the inter-frame silence, send, read the reply
    /// frame by its own length, decode.
    fn transact(
        &mut self,
        link: &mut dyn Link,
        request: &Request,
    ) -> Result<Response, DriverError> {
        if let Some(t) = self.quiet_since {
            let ready = t + self.gap;
            let now = Instant::now();
            if ready > now {
                std::thread::sleep(ready - now);
            }
        }
        let frame = proto::encode_request(self.slave, request);
        let sent = send_request(link, &frame, self.reply_timeout);
        self.quiet_since = Some(Instant::now());
        let deadline = sent?;
        let reply = self.read_frame(link, &deadline);
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
    ) -> Result<Vec<u8>, DriverError> {
        let mut buf = Vec::with_capacity(proto::MAX_FRAME);
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
            buf.extend_from_slice(&chunk[..n]);
            if buf.len() >= 3 && want == 3 {
                want = proto::response_len(&buf)
                    .map_err(|e| {
                        let _ = link.discard_input();
                        DriverError::Garbled(e.to_string())
                    })?
                    .unwrap_or(3);
            }
        }
        Ok(buf)
    }
}

impl Driver for ModbusDriver {
    fn poll(&mut self, link: &mut dyn Link) -> Result<Reading, DriverError> {
        let mut reading = Reading::default();
        for block in self.plan.clone() {
            let count = block.fields.len() as u16;
            let request = match self.map.position_kind {
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
            for (field, raw) in block.fields.iter().zip(regs) {
                match field {
                    Field::Position => reading.position = Some(self.map.value(raw)),
                    Field::Velocity => reading.velocity = Some(self.map.velocity_value(raw)),
                    Field::Pressure => reading.pressure = Some(self.map.pressure_value(raw)),
                    Field::Gear => {
                        reading.gear = Some(Gear::from_code(raw).ok_or_else(|| {
                            DriverError::Garbled(format!("unknown gear code {raw}"))
                        })?)
                    }
                    Field::Status => reading.fault = raw & self.map.fault_mask,
                }
            }
        }
        Ok(reading)
    }

    fn command(&mut self, link: &mut dyn Link, command: Command) -> Result<(), DriverError> {
        let mut addr = self.map.target;
        let value = match (command, self.map.is_gearbox()) {
            (Command::Control(c), _) => {
                addr = self.map.control.ok_or_else(|| {
                    DriverError::Unsupported(format!("{c}: this device has no control register"))
                })?;
                c.code()
            }
            (Command::Gear(g), true) => g.code(),
            (Command::Set(v), false) => self.map.raw(v).ok_or_else(|| {
                DriverError::Unsupported(format!(
                    "{v} does not fit register {} (scale {}, offset {})",
                    self.map.target, self.map.scale, self.map.offset
                ))
            })?,
            (Command::Gear(g), false) => {
                return Err(DriverError::Unsupported(format!(
                    "gear {g} sent to a device without a gear register"
                )))
            }
            (Command::Set(v), true) => {
                return Err(DriverError::Unsupported(format!(
                    "set point {v} sent to a transmission"
                )))
            }
        };
        let request = Request::WriteSingle { addr, value };
        self.transact(link, &request).map(|_| ())
    }
}

#[cfg(test)]
mod tests {
    use super::proto::{encode_exception, encode_request, encode_response, Exception};
    use super::*;
    use crate::driver::mock::{rx, tx, MockLink, Step};

    const T: Duration = Duration::from_millis(50);

    fn steer() -> ModbusDriver {
        ModbusDriver::new(alice_map(Role::Steer).unwrap(), 1, 115_200, T)
    }

    #[test]
    fn the_alice_maps_poll_in_one_read() {
        for role in [Role::Steer, Role::Gas, Role::Brake, Role::Trans] {
            let map = alice_map(role).unwrap();
            assert_eq!(map.read_plan().len(), 1, "{role}");
        }
        assert!(alice_map(Role::Obd).is_none());
    }

    #[test]
    fn holes_split_the_read_plan() {
        let mut m = RegisterMap::new(0);
        m.position = Some(10);
        m.velocity = Some(11);
        m.status = Some(20);
        let plan = m.read_plan();
        assert_eq!(plan.len(), 2);
        assert_eq!((plan[0].start, plan[0].fields.len()), (10, 2));
        assert_eq!((plan[1].start, plan[1].fields.len()), (20, 1));
    }

    #[test]
    fn scale_and_offset_convert_both_ways() {
        let mut m = RegisterMap::new(0);
        m.scale = 0.5;
        m.offset = 10.0;
        m.signed = true;
        assert_eq!(m.value((-4i16) as u16), 8.0);
        assert_eq!(m.raw(8.0), Some((-4i16) as u16));
        assert_eq!(m.raw(1e9), None);
        m.signed = false;
        assert_eq!(m.raw(9.0), None, "negative raw in an unsigned register");
        assert_eq!(m.value(0xFFFF), 65535.0 * 0.5 + 10.0);
    }

    #[test]
    fn a_register_map_loads_from_toml_and_rejects_typos() {
        let m: RegisterMap = toml::from_str(
            "target = 0\nposition = 0\nvelocity = 1\nstatus = 2\nfault_mask = 0x00FF\nscale = 0.0001\nsigned = true\n",
        )
        .unwrap();
        assert_eq!(m, alice_map(Role::Steer).unwrap());
        let err = toml::from_str::<RegisterMap>("target = 0\npositon = 1\n").unwrap_err();
        assert!(err.to_string().contains("positon"), "{err}");
        let m: RegisterMap =
            toml::from_str("target = 5\nposition = 7\nposition_kind = \"holding\"").unwrap();
        assert_eq!(m.position_kind, RegisterKind::Holding);
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
        assert_eq!(r.position, Some(-0.5));
        assert_eq!(r.velocity, Some(0.25));
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

    #[test]
    fn a_gear_is_written_as_its_code() {
        let mut d = ModbusDriver::new(alice_map(Role::Trans).unwrap(), 4, 9600, T);
        let req = encode_request(4, &Request::WriteSingle { addr: 0, value: 3 });
        let echo = encode_response(4, &Response::WriteSingle { addr: 0, value: 3 });
        let mut link = MockLink::new([tx(req), rx(echo)]);
        d.command(&mut link, Command::Gear(Gear::Drive)).unwrap();
        drop(link);
        let mut link = MockLink::new([]);
        assert!(matches!(
            d.command(&mut link, Command::Set(1.0)),
            Err(DriverError::Unsupported(_))
        ));
        assert!(matches!(
            steer().command(&mut link, Command::Gear(Gear::Park)),
            Err(DriverError::Unsupported(_))
        ));
        assert!(matches!(
            steer().command(&mut link, Command::Set(7.0)),
            Err(DriverError::Unsupported(_))
        ));
    }

    #[test]
    fn the_trans_reports_its_gear() {
        let mut d = ModbusDriver::new(alice_map(Role::Trans).unwrap(), 4, 9600, T);
        let req = encode_request(4, &Request::ReadInput { addr: 0, count: 2 });
        let reply = encode_response(4, &Response::ReadInput(vec![1, 0]));
        let mut link = MockLink::new([tx(&req), rx(reply)]);
        assert_eq!(d.poll(&mut link).unwrap().gear, Some(Gear::Reverse));
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
        let mut d = ModbusDriver::new(alice_map(Role::Gas).unwrap(), 2, 1200, T);
        let req = encode_request(2, &Request::ReadInput { addr: 0, count: 2 });
        let reply = encode_response(2, &Response::ReadInput(vec![0, 0]));
        let mut link = MockLink::new([tx(&req), rx(&reply), tx(&req), rx(&reply)]);
        d.poll(&mut link).unwrap();
        let first_done = Instant::now();
        d.poll(&mut link).unwrap();
        assert!(first_done.elapsed() >= proto::frame_gap(1200));
    }
}
