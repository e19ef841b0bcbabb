//! Device side of the adrive ASCII line protocol (see [`crate::driver::line`]).

use super::device::{Plant, Reply, Responder};
use crate::config::protocol_map::LineMap;
use crate::driver::line::{decode_request, encode_status, Request, MAX_LINE};

/// A line-protocol device with the device's keys and words.
pub(crate) struct LineDevice(pub LineMap);

impl Responder for LineDevice {
    fn respond(&mut self, input: &[u8], plant: &mut dyn Plant) -> Option<Reply> {
        let Some(end) = input.iter().position(|&b| b == b'\n') else {
            // A line that never ends is noise: drop it once it is too long.
            return (input.len() > MAX_LINE).then(|| Reply {
                consumed: input.len(),
                bytes: b"err line too long\n".to_vec(),
                ..Reply::default()
            });
        };
        let consumed = end + 1;
        let bytes = match decode_request(&input[..consumed], &self.0) {
            Ok(Request::Poll) => encode_status(&plant.reading(), &self.0),
            Ok(Request::Command(c)) => match plant.command(c) {
                Ok(()) => b"ok\n".to_vec(),
                Err(e) => format!("err {e}\n").into_bytes(),
            },
            Err(e) => format!("err {e}\n").into_bytes(),
        };
        Some(Reply {
            consumed,
            bytes,
            ..Reply::default()
        })
    }
}
