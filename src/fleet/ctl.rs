//! `adrive ctl --vehicle ID …`: one operation to a vehicle of the fleet, asked at its
//! `adrive/<id>/ctl` in the control socket's own messages (a [`Request`] out, a
//! [`Msg::Reply`] back), so that it prints and exits as over the local socket. So far a
//! vehicle answers the status and refuses the rest ([`super::member`]).

use super::keys;
use crate::config::ros2::Mode;
use crate::socket::client::{ClientError, REPLY_WITHIN};
use crate::socket::proto::{Answer, Msg, Op, Request};
use zenoh::Wait;

/// Ask vehicle `id`, through `connect`, to do `op`; its answer.
pub(crate) fn once(connect: &[String], id: &str, op: Op) -> Result<Answer, ClientError> {
    let refused = |e: String| ClientError::Refused(e);
    let session = super::open(&super::Network {
        mode: Mode::Client,
        connect,
        listen: &[],
        multicast_scouting: false,
    })
    .map_err(|e| refused(e.to_string()))?;
    let answer = ask(&session, connect, id, op);
    let _ = session.close().wait();
    answer
}

fn ask(
    session: &zenoh::Session,
    connect: &[String],
    id: &str,
    op: Op,
) -> Result<Answer, ClientError> {
    let refused = |e: String| ClientError::Refused(e);
    // Is it there at all: a vehicle not on the network is not a vehicle that is slow.
    let there = session
        .liveliness()
        .get(keys::token(id))
        .timeout(REPLY_WITHIN)
        .wait()
        .map_err(|e| refused(format!("fleet: asking for {id}: {e}")))?;
    if !matches!(there.recv(), Ok(r) if r.result().is_ok()) {
        return Err(refused(format!(
            "no vehicle {id} on the fleet's network (through {}; `adrive fleet` lists those there)",
            connect.join(", ")
        )));
    }
    let request = serde_json::to_vec(&Request { id: 1, op }).expect("a request serializes");
    let replies = session
        .get(keys::ctl(id))
        .payload(request)
        .timeout(REPLY_WITHIN)
        .wait()
        .map_err(|e| refused(format!("fleet: asking {id}: {e}")))?;
    while let Ok(reply) = replies.recv() {
        let Ok(sample) = reply.result() else {
            continue;
        };
        let bytes = sample.payload().to_bytes();
        match serde_json::from_slice::<Msg>(&bytes) {
            Ok(Msg::Reply { id: 1, answer }) => return Ok(answer),
            Ok(_) => continue,
            Err(e) => return Err(refused(format!("{id} answered what does not read: {e}"))),
        }
    }
    Err(ClientError::NoReply(REPLY_WITHIN))
}
