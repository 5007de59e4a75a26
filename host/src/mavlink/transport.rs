//! The bytes between lluavd and the autopilot.
//!
//! UDP (`udpin:`, `udpout:`) is lluavd's own, over tokio's `UdpSocket`
//! and the `mavlink` crate's frame parser: every datagram is parsed on its
//! own and its frames keep the address they came from, so the link can
//! tell the autopilot's packets from anyone else's, and lluavd sends to
//! the address the link names (the `mavlink` crate's UDP connection
//! replies to whoever sent the last datagram, garbage included). On
//! `udpout:` it always sends to the configured address. Serial and TCP
//! have one peer and use the crate's connection, reconnected when it
//! fails.
//!
//! With a signing key, everything sent is signed and only frames with a
//! good signature are read (see `signing`).

use std::io;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use ::mavlink::dialects::ardupilotmega::MavMessage;
use ::mavlink::error::MessageReadError;
use ::mavlink::{AsyncConnection, AsyncMavConnection as _, MavHeader, MavlinkReader, SigningData};
use tokio::net::UdpSocket;

use super::error::MavError;
use super::signing::SigningKey;

/// How long to wait before reconnecting a failed serial or TCP link.
const RECONNECT_DELAY: Duration = Duration::from_secs(1);
/// The largest UDP datagram.
const MAX_DATAGRAM: usize = 65_536;

type Conn = AsyncConnection<MavMessage>;

/// A MAVLink frame received, and where it came from (`None` on a link
/// with one peer).
#[derive(Clone, Debug)]
pub struct Packet {
    /// The sender's address.
    pub from: Option<SocketAddr>,
    /// The frame's header.
    pub header: MavHeader,
    /// The message.
    pub msg: MavMessage,
}

enum Kind {
    /// lluavd's own UDP; `fixed` is `udpout:`'s address.
    Udp {
        socket: UdpSocket,
        fixed: Option<SocketAddr>,
    },
    /// The crate's serial or TCP connection.
    Stream {
        address: String,
        conn: Mutex<Option<Arc<Conn>>>,
        key: Option<SigningKey>,
    },
}

/// The link's bytes.
pub struct Transport {
    kind: Kind,
    signing: Option<Arc<SigningData>>,
    sequence: AtomicU8,
}

fn unpoison<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

async fn resolve(address: &str) -> io::Result<SocketAddr> {
    tokio::net::lookup_host(address).await?.next().ok_or_else(|| {
        io::Error::new(
            io::ErrorKind::AddrNotAvailable,
            format!("{address} has no address"),
        )
    })
}

async fn connect(address: &str, key: Option<&SigningKey>) -> io::Result<Conn> {
    let mut conn = ::mavlink::connect_async::<MavMessage>(address).await?;
    // ArduPilot on a serial port speaks MAVLink 1 until it hears MAVLink 2.
    conn.set_allow_recv_any_version(key.is_none());
    conn.setup_signing(key.map(SigningKey::config));
    Ok(conn)
}

/// The frames in one datagram that `signing` accepts (all of them
/// without a key); garbage between and around them is skipped.
pub fn parse_datagram(bytes: &[u8], signing: Option<&SigningData>) -> Vec<(MavHeader, MavMessage)> {
    let mut reader = MavlinkReader::new(bytes);
    let mut frames = Vec::new();
    loop {
        match reader.read_any_message_signed::<MavMessage>(signing) {
            Ok(frame) => frames.push(frame),
            // A frame with a good checksum but a payload this dialect
            // cannot read: skipped like garbage.
            Err(MessageReadError::Parse(_)) => {}
            Err(MessageReadError::Io(_)) => return frames,
        }
    }
}

impl Transport {
    /// Opens `address` (the `mavlink` crate's syntax), signing with `key`.
    pub async fn open(address: &str, key: Option<&SigningKey>) -> io::Result<Transport> {
        let kind = match address.split_once(':') {
            Some(("udpin", at)) => Kind::Udp {
                socket: UdpSocket::bind(resolve(at).await?).await?,
                fixed: None,
            },
            Some(("udpout", to)) => {
                let to = resolve(to).await?;
                let any: SocketAddr = if to.is_ipv4() { "0.0.0.0:0" } else { "[::]:0" }
                    .parse()
                    .map_err(io::Error::other)?;
                Kind::Udp {
                    socket: UdpSocket::bind(any).await?,
                    fixed: Some(to),
                }
            }
            _ => Kind::Stream {
                address: address.to_owned(),
                conn: Mutex::new(Some(Arc::new(connect(address, key).await?))),
                key: key.cloned(),
            },
        };
        Ok(Transport {
            kind,
            signing: key.map(SigningKey::data),
            sequence: AtomicU8::new(0),
        })
    }

    /// The next frames: those of one datagram, or one frame of a stream.
    /// A failed stream is reconnected here; only a failing UDP socket
    /// is an error.
    pub async fn recv(&self) -> io::Result<Vec<Packet>> {
        match &self.kind {
            Kind::Udp { socket, .. } => {
                let mut buf = vec![0u8; MAX_DATAGRAM];
                let (n, from) = socket.recv_from(&mut buf).await?;
                let bytes = buf.get(..n).unwrap_or_default();
                Ok(parse_datagram(bytes, self.signing.as_deref())
                    .into_iter()
                    .map(|(header, msg)| Packet {
                        from: Some(from),
                        header,
                        msg,
                    })
                    .collect())
            }
            Kind::Stream { address, conn, key } => Ok(recv_stream(address, conn, key.as_ref()).await),
        }
    }

    /// Sends `msg` with `header` (its sequence is the link's) to `to`, or
    /// to `udpout:`'s address, or to the one peer of a serial or TCP link.
    pub async fn send(
        &self,
        to: Option<SocketAddr>,
        header: MavHeader,
        msg: &MavMessage,
    ) -> Result<(), MavError> {
        let header = MavHeader {
            sequence: self.sequence.fetch_add(1, Ordering::Relaxed),
            ..header
        };
        match &self.kind {
            Kind::Udp { socket, fixed } => {
                let to = fixed
                    .or(to)
                    .ok_or_else(|| MavError::Send("no autopilot followed yet".into()))?;
                let mut frame = Vec::with_capacity(300);
                ::mavlink::write_v2_msg_signed(&mut frame, header, msg, self.signing.as_deref())
                    .map_err(|e| MavError::Send(e.to_string()))?;
                socket
                    .send_to(&frame, to)
                    .await
                    .map(|_| ())
                    .map_err(|e| MavError::Send(e.to_string()))
            }
            Kind::Stream { address, conn, .. } => {
                let conn = unpoison(conn)
                    .clone()
                    .ok_or_else(|| MavError::Send(format!("not connected to {address}")))?;
                conn.send(&header, msg)
                    .await
                    .map(|_| ())
                    .map_err(|e| MavError::Send(e.to_string()))
            }
        }
    }
}

/// One frame of a serial or TCP link, reconnecting it as long as it fails.
async fn recv_stream(
    address: &str,
    slot: &Mutex<Option<Arc<Conn>>>,
    key: Option<&SigningKey>,
) -> Vec<Packet> {
    loop {
        let conn = unpoison(slot).clone();
        let Some(conn) = conn else {
            tokio::time::sleep(RECONNECT_DELAY).await;
            match connect(address, key).await {
                Ok(c) => {
                    tracing::info!(address, "MAVLink reconnected");
                    *unpoison(slot) = Some(Arc::new(c));
                }
                Err(e) => tracing::debug!(error = %e, "MAVLink reconnect failed"),
            }
            continue;
        };
        match conn.recv().await {
            Ok((header, msg)) => {
                return vec![Packet {
                    from: None,
                    header,
                    msg,
                }];
            }
            Err(MessageReadError::Parse(e)) => tracing::debug!(error = %e, "MAVLink frame dropped"),
            Err(MessageReadError::Io(e)) => {
                tracing::warn!(error = %e, address, "MAVLink connection failed; reconnecting");
                *unpoison(slot) = None;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use ::mavlink::dialects::ardupilotmega::HEARTBEAT_DATA;

    use super::*;

    fn frame(system: u8, signing: Option<&SigningData>) -> Vec<u8> {
        let header = MavHeader {
            system_id: system.into(),
            component_id: 1,
            sequence: 0,
        };
        let mut bytes = Vec::new();
        ::mavlink::write_v2_msg_signed(
            &mut bytes,
            header,
            &MavMessage::HEARTBEAT(HEARTBEAT_DATA::DEFAULT),
            signing,
        )
        .unwrap();
        bytes
    }

    fn systems(frames: &[(MavHeader, MavMessage)]) -> Vec<u32> {
        frames.iter().map(|(h, _)| h.system_id).collect()
    }

    #[test]
    fn every_frame_of_a_datagram_is_read_and_garbage_around_them_skipped() {
        let mut datagram = b"\xfd\x09garbage".to_vec();
        datagram.extend(frame(1, None));
        datagram.extend(b"\xfe\x00\x01");
        datagram.extend(frame(2, None));
        datagram.extend(&frame(3, None)[..10]);
        assert_eq!(systems(&parse_datagram(&datagram, None)), [1, 2]);
        assert!(parse_datagram(b"", None).is_empty());
    }

    #[test]
    fn with_a_key_only_frames_signed_with_it_are_read() {
        let ours = SigningKey::from_hex(&"11".repeat(32)).unwrap();
        let theirs = SigningKey::from_hex(&"22".repeat(32)).unwrap();
        let (sender, receiver) = (ours.data(), ours.data());
        let mut datagram = frame(1, Some(&sender));
        datagram.extend(frame(2, None));
        datagram.extend(frame(3, Some(&theirs.data())));
        datagram.extend(frame(4, Some(&sender)));
        assert_eq!(systems(&parse_datagram(&datagram, Some(&receiver))), [1, 4]);
        // A frame signed later is read; the same bytes again are a replay.
        let replay = frame(5, Some(&sender));
        assert_eq!(systems(&parse_datagram(&replay, Some(&receiver))), [5]);
        assert!(parse_datagram(&replay, Some(&receiver)).is_empty());
    }
}
