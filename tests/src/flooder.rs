//! A stand-in broker that misbehaves on purpose: it speaks just enough
//! MQTT 5 to accept one vehicle's CONNECT and SUBSCRIBE, then floods it
//! with QoS 1 requests and never reads or acknowledges anything again
//! (a compromised broker, or whoever sits in the middle of plain
//! `mqtt://`). The flood waits for [`Flooder::go`], so that the vehicle's
//! memory can be read before it.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc;

use crate::WAIT;

/// What the flood sends.
#[derive(Clone, Copy, Debug)]
pub struct Flood {
    /// Bytes to send in all.
    pub bytes: u64,
    /// Bytes of each request envelope.
    pub message: usize,
    /// Client ids the requests come from, in turn.
    pub clients: usize,
}

/// The stand-in broker, listening on a free loopback port.
pub struct Flooder {
    /// Its port on 127.0.0.1.
    pub port: u16,
    sent: Arc<AtomicU64>,
    ended: Arc<AtomicBool>,
    subscribed: mpsc::Receiver<()>,
    go: mpsc::Sender<()>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Flooder {
    /// Listens for vehicle `vehicle` and floods it as `flood` says once
    /// told to.
    pub fn start(vehicle: &str, flood: Flood) -> Flooder {
        let listener = TcpListener::bind("127.0.0.1:0").expect("a free port");
        let port = listener.local_addr().expect("local address").port();
        let sent = Arc::new(AtomicU64::new(0));
        let ended = Arc::new(AtomicBool::new(false));
        let (subscribed_tx, subscribed) = mpsc::channel();
        let (go, go_rx) = mpsc::channel();
        let (sent2, ended2, vehicle) = (Arc::clone(&sent), Arc::clone(&ended), vehicle.to_owned());
        let thread = std::thread::spawn(move || {
            let Ok((mut stream, _)) = listener.accept() else {
                return;
            };
            if handshake(&mut stream).is_ok() {
                let _ = subscribed_tx.send(());
                if go_rx.recv().is_ok() {
                    let _ = flood_with(&mut stream, &vehicle, flood, &sent2, &ended2);
                }
            }
            ended2.store(true, Ordering::SeqCst);
            // Held open until the test ends: the vehicle must not see a
            // closed connection and start over.
            let _ = go_rx.recv();
        });
        Flooder {
            port,
            sent,
            ended,
            subscribed,
            go,
            thread: Some(thread),
        }
    }

    /// `mqtt://127.0.0.1:PORT`.
    pub fn url(&self) -> String {
        format!("mqtt://127.0.0.1:{}", self.port)
    }

    /// Waits until the vehicle connected and subscribed.
    pub fn wait_subscribed(&self) {
        self.subscribed
            .recv_timeout(WAIT)
            .expect("the vehicle connected and subscribed in time");
    }

    /// Starts the flood.
    pub fn go(&self) {
        let _ = self.go.send(());
    }

    /// Bytes sent so far (taken by the vehicle's socket).
    pub fn sent(&self) -> u64 {
        self.sent.load(Ordering::SeqCst)
    }

    /// Whether the flood has ended: all sent, or the vehicle closed the
    /// connection.
    pub fn ended(&self) -> bool {
        self.ended.load(Ordering::SeqCst)
    }
}

impl Drop for Flooder {
    fn drop(&mut self) {
        // The thread ends with the flood (or on its first failed write, as
        // the vehicle goes with the test), and with the sender gone it does
        // not hold the connection: no join, which could wait for a write.
        self.ended.store(true, Ordering::SeqCst);
        let (orphan, _) = mpsc::channel();
        drop(std::mem::replace(&mut self.go, orphan));
        drop(self.thread.take());
    }
}

/// One MQTT packet: (first byte, body).
fn read_packet(stream: &mut TcpStream) -> std::io::Result<(u8, Vec<u8>)> {
    let mut first = [0u8; 1];
    stream.read_exact(&mut first)?;
    let (mut len, mut shift) = (0usize, 0);
    loop {
        let mut b = [0u8; 1];
        stream.read_exact(&mut b)?;
        len |= usize::from(b[0] & 0x7f) << shift;
        if b[0] & 0x80 == 0 {
            break;
        }
        shift += 7;
    }
    let mut body = vec![0u8; len];
    stream.read_exact(&mut body)?;
    Ok((first[0], body))
}

/// A variable byte integer.
fn varint(mut n: usize, out: &mut Vec<u8>) {
    loop {
        let byte = (n % 128) as u8;
        n /= 128;
        if n == 0 {
            out.push(byte);
            return;
        }
        out.push(byte | 0x80);
    }
}

/// CONNECT → CONNACK, then everything up to the SUBSCRIBE → SUBACK
/// (granting QoS 1).
fn handshake(stream: &mut TcpStream) -> std::io::Result<()> {
    stream.set_read_timeout(Some(WAIT))?;
    let (first, _) = read_packet(stream)?;
    if first >> 4 != 1 {
        return Err(std::io::Error::other("not a CONNECT"));
    }
    // Session present 0, Success, no properties.
    stream.write_all(&[0x20, 0x03, 0x00, 0x00, 0x00])?;
    loop {
        let (first, body) = read_packet(stream)?;
        if first >> 4 == 8 && body.len() >= 2 {
            // Packet id, no properties, QoS 1 granted.
            stream.write_all(&[0x90, 0x04, body[0], body[1], 0x00, 0x01])?;
            return Ok(());
        }
    }
}

/// QoS 1 PUBLISHes of requests, each from the next client id with a new
/// request id, padded to `flood.message` bytes, until `flood.bytes` went
/// out or the vehicle closed the connection.
fn flood_with(
    stream: &mut TcpStream,
    vehicle: &str,
    flood: Flood,
    sent: &AtomicU64,
    stop: &AtomicBool,
) -> std::io::Result<()> {
    stream.set_write_timeout(Some(WAIT))?;
    let mut n: u64 = 0;
    while sent.load(Ordering::SeqCst) < flood.bytes && !stop.load(Ordering::SeqCst) {
        let client = format!("flood{}", n % flood.clients.max(1) as u64);
        let topic = format!("lluav/{vehicle}/req/{client}");
        // Every other request pads its frame (queued bytes), the others
        // an extra member (read, then dropped).
        let head = format!(r#"{{"id":"f{n}","frame":"#);
        let room = flood.message.saturating_sub(head.len() + 32);
        let payload = if n.is_multiple_of(2) {
            format!(r#"{head}"set_param p:{}"}}"#, "1".repeat(room))
        } else {
            format!(r#"{head}"state","pad":"{}"}}"#, "x".repeat(room))
        };
        let pkid = (n % 65_535 + 1) as u16;
        let mut body = Vec::with_capacity(payload.len() + topic.len() + 8);
        body.extend_from_slice(&(topic.len() as u16).to_be_bytes());
        body.extend_from_slice(topic.as_bytes());
        body.extend_from_slice(&pkid.to_be_bytes());
        body.push(0x00);
        body.extend_from_slice(payload.as_bytes());
        let mut packet = vec![0x32];
        varint(body.len(), &mut packet);
        packet.extend_from_slice(&body);
        stream.write_all(&packet)?;
        sent.fetch_add(packet.len() as u64, Ordering::SeqCst);
        n += 1;
    }
    Ok(())
}
