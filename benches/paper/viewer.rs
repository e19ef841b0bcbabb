//! A Foxglove viewer for the bench: connects to adrive's live view, subscribes to
//! every channel it advertises and reads everything until stopped, counting the
//! messages (section 10).

use std::net::{SocketAddr, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::Arc;
use std::time::Duration;
use tungstenite::client::IntoClientRequest;
use tungstenite::Message;

/// A TCP port free on loopback right now.
pub fn free_tcp_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// One viewer reading on a thread of its own.
pub struct Viewer {
    stop: Arc<AtomicBool>,
    received: Arc<AtomicU64>,
    thread: std::thread::JoinHandle<()>,
}

impl Viewer {
    pub fn start(addr: SocketAddr) -> Viewer {
        let stream = TcpStream::connect(addr).expect("the live view listens");
        stream
            .set_read_timeout(Some(Duration::from_millis(200)))
            .unwrap();
        let mut req = format!("ws://{addr}").into_client_request().unwrap();
        req.headers_mut()
            .insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse().unwrap());
        let (mut ws, _) = tungstenite::client::client(req, stream).expect("a handshake");
        let mut ids = Vec::new();
        while ids.is_empty() {
            if let Ok(Message::Text(t)) = ws.read() {
                let v: serde_json::Value = serde_json::from_str(&t).unwrap();
                if v["op"] == "advertise" {
                    ids = v["channels"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .map(|c| c["id"].clone())
                        .collect();
                }
            }
        }
        let subs: Vec<_> = ids
            .iter()
            .enumerate()
            .map(|(i, c)| serde_json::json!({"id": i, "channelId": c}))
            .collect();
        let sub = serde_json::json!({"op": "subscribe", "subscriptions": subs});
        ws.send(Message::text(sub.to_string())).unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let received = Arc::new(AtomicU64::new(0));
        let (s, r) = (stop.clone(), received.clone());
        let thread = std::thread::spawn(move || {
            while !s.load(Relaxed) {
                match ws.read() {
                    Ok(Message::Binary(_)) => {
                        r.fetch_add(1, Relaxed);
                    }
                    Ok(_) => {}
                    Err(tungstenite::Error::Io(e))
                        if matches!(
                            e.kind(),
                            std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                        ) => {}
                    Err(_) => return,
                }
            }
        });
        Viewer {
            stop,
            received,
            thread,
        }
    }

    /// Stop reading; the messages received.
    pub fn stop(self) -> u64 {
        self.stop.store(true, Relaxed);
        let _ = self.thread.join();
        self.received.load(Relaxed)
    }
}
