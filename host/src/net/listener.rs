//! The accept loop and each connection's way from accept to its session:
//! TLS (for `wss://`), the request head within the handshake deadline, the
//! verdict, a slot, the `101`, then the [`Connection`]. Shutdown: stop
//! accepting, let sessions answer what already arrived, close them with
//! 1001, wait (bounded) for them to go.

use std::future::Future;
use std::net::{IpAddr, SocketAddr};
use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tokio::task::JoinSet;
use tokio::time::{Instant, timeout, timeout_at};
use tokio_rustls::TlsAcceptor;
use tracing::{debug, info, warn};

use super::buffers::Buffers;
use super::connection::{Connection, Context};
use lluav_core::websocket::handshake::{self as upgrade_check, Rejection, Request};

use super::handshake::{self, HeadError, Refusal};
use super::report::{Offence, Reports};
use super::slots::{Capacity, Full, Held, Pending, Slots};
use super::subscriber;
use super::{Handler, Http, LINGER, Limits, Policy};

/// Everything a listener serves with.
#[derive(Clone, Default)]
pub struct Config {
    /// Limits and timeouts.
    pub limits: Limits,
    /// The Origin/Host policy.
    pub policy: Policy,
    /// `Some`: `wss://`, TLS with this acceptor on the same port.
    pub tls: Option<TlsAcceptor>,
    /// Answers plain HTTP requests (the daemon's console); `None`: 404.
    pub http: Option<Http>,
}

impl Config {
    fn capacity(&self) -> Capacity {
        Capacity {
            handshakes: self.limits.max_handshakes,
            handshakes_per_ip: self.limits.max_handshakes_per_ip,
            sessions: self.limits.max_connections,
            sessions_per_ip: self.limits.max_sessions_per_ip,
        }
    }
}

/// What every connection task of one listener shares.
struct Shared<H> {
    handler: Arc<H>,
    config: Config,
    slots: Arc<Slots>,
    reports: Reports,
    buffers: Buffers,
}

impl<H> Shared<H> {
    fn new(handler: Arc<H>, config: Config) -> Self {
        Shared {
            handler,
            slots: Slots::new(config.capacity()),
            buffers: Buffers::new(config.limits.response_capacity),
            config,
            reports: Reports::default(),
        }
    }
}

/// Serves connections on `listener` with `handler` until `shutdown`
/// completes, then stops accepting, lets every session answer the frames
/// it already received, closes them with 1001 and returns once they are
/// gone (or [`Limits::shutdown_grace`] has passed).
pub async fn serve<H: Handler>(
    listener: TcpListener,
    handler: Arc<H>,
    config: Config,
    shutdown: impl Future<Output = ()>,
) {
    let (stop_tx, stop_rx) = watch::channel(false);
    let shared = Arc::new(Shared::new(handler, config));
    let mut tasks = JoinSet::new();
    tokio::pin!(shutdown);
    loop {
        tokio::select! {
            () = &mut shutdown => break,
            Some(_) = tasks.join_next(), if !tasks.is_empty() => {}
            accepted = listener.accept() => {
                let (stream, peer) = match accepted {
                    Ok(a) => a,
                    Err(e) => {
                        // Typically EMFILE: back off instead of spinning.
                        warn!(error = %e, "accept failed");
                        tokio::time::sleep(Duration::from_millis(100)).await;
                        continue;
                    }
                };
                let deadline = Instant::now() + shared.config.limits.handshake_timeout;
                let (pending, dropped) = shared.slots.begin(peer.ip());
                for ip in dropped {
                    shared.reports.note(ip, Offence::HandshakeDropped);
                }
                tasks.spawn(accept(stream, peer, pending, deadline, Arc::clone(&shared), stop_rx.clone()));
            }
        }
    }
    drop(listener);
    info!(sessions = shared.slots.sessions(), "shutting down");
    let _ = stop_tx.send(true);
    let grace = shared.config.limits.shutdown_grace;
    let drained = timeout(grace, async { while tasks.join_next().await.is_some() {} }).await;
    if drained.is_err() {
        warn!(
            left = tasks.len(),
            "connections still open after the grace period; dropping them"
        );
        tasks.shutdown().await;
    }
}

/// Serves one connection over any byte stream, from its request head to
/// its close, with a slot registry of its own: the fuzz targets and tests
/// pass in-memory streams. `local` is the address the client connected to.
pub async fn serve_stream<S, H>(
    stream: S,
    peer: SocketAddr,
    local: IpAddr,
    handler: Arc<H>,
    config: Config,
    stop: watch::Receiver<bool>,
) where
    S: AsyncRead + AsyncWrite + Unpin,
    H: Handler,
{
    let deadline = Instant::now() + config.limits.handshake_timeout;
    let shared = Shared::new(handler, config);
    let (pending, _) = shared.slots.begin(peer.ip());
    upgrade(stream, None, peer, local, pending, deadline, &shared, stop).await;
}

/// A TCP connection: TLS first for `wss://`, then the upgrade.
async fn accept<H: Handler>(
    tcp: TcpStream,
    peer: SocketAddr,
    pending: Pending,
    deadline: Instant,
    shared: Arc<Shared<H>>,
    stop: watch::Receiver<bool>,
) {
    if let Err(e) = tcp.set_nodelay(true) {
        debug!(%peer, error = %e, "TCP_NODELAY not set");
    }
    let Ok(local) = tcp.local_addr() else {
        return;
    };
    let fd = Some(std::os::fd::AsRawFd::as_raw_fd(&tcp));
    let Some(acceptor) = shared.config.tls.clone() else {
        upgrade(tcp, fd, peer, local.ip(), pending, deadline, &shared, stop).await;
        return;
    };
    // Boxed: a TLS stream is kilobytes, and inline it would make every
    // task that large, plain ones too (all tasks have one type).
    let tls = tokio::select! {
        biased;
        () = pending.cancel.notified() => return,
        tls = Box::pin(timeout_at(deadline, acceptor.accept(tcp))) => tls,
    };
    match tls {
        Ok(Ok(stream)) => {
            Box::pin(upgrade(
                stream,
                fd,
                peer,
                local.ip(),
                pending,
                deadline,
                &shared,
                stop,
            ))
            .await
        }
        Ok(Err(e)) => debug!(%peer, error = %e, "TLS handshake failed"),
        Err(_) => shared.reports.note(peer.ip(), Offence::HandshakeTimeout),
    }
}

/// Reads and judges the request head, answers it, and serves the session
/// if it is an acceptable upgrade with a slot free. `fd` is the TCP
/// socket under `stream`, when there is one.
#[allow(clippy::too_many_arguments)]
async fn upgrade<S, H>(
    mut stream: S,
    fd: Option<std::os::fd::RawFd>,
    peer: SocketAddr,
    local: IpAddr,
    pending: Pending,
    deadline: Instant,
    shared: &Shared<H>,
    stop: watch::Receiver<bool>,
) where
    S: AsyncRead + AsyncWrite + Unpin,
    H: Handler,
{
    let mut buf = Vec::new();
    let head = tokio::select! {
        biased;
        () = pending.cancel.notified() => return,
        head = timeout_at(deadline, handshake::read_head(&mut stream, &mut buf)) => head,
    };
    let len = match head {
        Ok(Ok(len)) => len,
        Ok(Err(HeadError::Closed)) => return,
        Ok(Err(HeadError::TooLarge)) => {
            let refusal = Refusal::Request(Rejection::TooLarge);
            return refuse(stream, peer, &refusal, Offence::BadRequest, deadline, shared).await;
        }
        Err(_) => return shared.reports.note(peer.ip(), Offence::HandshakeTimeout),
    };
    let leftover = buf.split_off(len);
    let rules = shared.config.policy.at(local, shared.config.tls.is_some());
    let (key, events) = match upgrade_check::judge(&buf, &rules) {
        Ok(Request::Upgrade(upgrade))
            if subscriber::is_events(upgrade.target) && !serves_events(&*shared.handler) =>
        {
            return answer_and_close(stream, &handshake::not_found(), deadline).await;
        }
        Ok(Request::Upgrade(upgrade)) => (*upgrade.key, subscriber::is_events(upgrade.target)),
        Ok(Request::Plain { method, target }) => {
            let answer = shared
                .config
                .http
                .as_ref()
                .map_or_else(handshake::not_found, |http| http(method, target));
            return answer_and_close(stream, &answer, deadline).await;
        }
        Err(why) => {
            let offence = match why {
                Rejection::Forbidden(_) => Offence::Forbidden,
                _ => Offence::BadRequest,
            };
            return refuse(stream, peer, &Refusal::Request(why), offence, deadline, shared).await;
        }
    };
    let slot = match take_slot(shared, pending, peer) {
        Ok(slot) => slot,
        Err((refusal, offence)) => return refuse(stream, peer, &refusal, offence, deadline, shared).await,
    };
    // On the bus before the `101`: all that follows the upgrade is told.
    let early = events.then(|| shared.handler.subscribe()).flatten();
    let answered = timeout_at(deadline, async {
        stream.write_all(&handshake::switching_protocols(&key)).await?;
        stream.flush().await
    })
    .await;
    if !matches!(answered, Ok(Ok(()))) {
        return;
    }
    // The head is not needed for the session's whole life.
    drop(buf);
    if events {
        if let Some(fd) = fd {
            subscriber::small_send_buffer(fd);
        }
        let cx = context(shared);
        subscriber::serve(stream, leftover, peer, slot, cx, stop, early).await;
    } else {
        session(stream, peer, leftover, slot, shared, stop).await;
    }
}

/// A session slot for `peer`'s acceptable upgrade (noting the address
/// whose session it reclaimed, if any), or the refusal and the offence it
/// counts as when there is none.
fn take_slot<H: Handler>(
    shared: &Shared<H>,
    pending: Pending,
    peer: SocketAddr,
) -> Result<Held, (Refusal, Offence)> {
    match shared.slots.admit(pending, peer.ip()) {
        Ok((slot, reclaimed)) => {
            if let Some(ip) = reclaimed {
                shared.reports.note(ip, Offence::SessionReclaimed);
            }
            Ok(slot)
        }
        Err(full) => {
            let offence = match full {
                Full::Address => Offence::TooManySessions,
                Full::Server => Offence::ServerFull,
            };
            Err((unavailable(full, &shared.config.limits), offence))
        }
    }
}

/// Whether `handler` serves the `/events` endpoint.
fn serves_events<H: Handler>(handler: &H) -> bool {
    handler.subscribe().is_some()
}

fn context<H: Handler>(shared: &Shared<H>) -> Context<'_, H> {
    Context {
        handler: &*shared.handler,
        buffers: &shared.buffers,
        limits: shared.config.limits,
        reports: &shared.reports,
    }
}

/// The session after its `101`.
async fn session<S, H>(
    stream: S,
    peer: SocketAddr,
    leftover: Vec<u8>,
    slot: Held,
    shared: &Shared<H>,
    stop: watch::Receiver<bool>,
) where
    S: AsyncRead + AsyncWrite + Unpin,
    H: Handler,
{
    Connection::new(stream, leftover, peer, Some(slot), context(shared))
        .run(stop)
        .await;
}

/// The 503 for a connection that found no slot.
fn unavailable(full: Full, limits: &Limits) -> Refusal {
    Refusal::Unavailable(match full {
        Full::Address => format!(
            "this address already has {} sessions, the most allowed (--max-sessions-per-ip); try again later",
            limits.max_sessions_per_ip
        ),
        Full::Server => format!(
            "every session slot ({}) is taken (--max-connections); try again later",
            limits.max_connections
        ),
    })
}

/// Answers a refused request with its status, notes the offence, closes.
async fn refuse<S, H>(
    stream: S,
    peer: SocketAddr,
    refusal: &Refusal,
    offence: Offence,
    deadline: Instant,
    shared: &Shared<H>,
) where
    S: AsyncRead + AsyncWrite + Unpin,
{
    debug!(%peer, status = refusal.code(), "{refusal}");
    shared.reports.note(peer.ip(), offence);
    answer_and_close(stream, &refusal.to_bytes(), deadline).await;
}

/// Writes `answer`, ends the stream and reads on briefly, so that the
/// client reads the answer before the socket closes.
async fn answer_and_close<S: AsyncRead + AsyncWrite + Unpin>(
    mut stream: S,
    answer: &[u8],
    deadline: Instant,
) {
    let wrote = timeout_at(deadline, async {
        stream.write_all(answer).await?;
        stream.shutdown().await
    })
    .await;
    if !matches!(wrote, Ok(Ok(()))) {
        return;
    }
    let mut sink = vec![0u8; 1024];
    let _ = timeout(LINGER, async {
        while let Ok(1..) = stream.read(&mut sink).await {}
    })
    .await;
}

#[cfg(test)]
mod tests {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    use super::*;
    use crate::net::Echo;

    /// Sends `request` to a connection served with `config`; its answer.
    async fn answer(config: Config, request: &str) -> String {
        let (mut client, server) = tokio::io::duplex(4096);
        let (_stop, stop) = watch::channel(false);
        let peer: SocketAddr = ([127, 0, 0, 1], 1).into();
        let serve = serve_stream(server, peer, peer.ip(), Arc::new(Echo), config, stop);
        let talk = async {
            client.write_all(request.as_bytes()).await.expect("written");
            let mut out = Vec::new();
            client.read_to_end(&mut out).await.expect("read");
            String::from_utf8(out).expect("text")
        };
        let ((), out) = tokio::join!(serve, talk);
        out
    }

    #[tokio::test]
    async fn plain_http_goes_to_the_handler_passed_in_or_gets_404() {
        let request = "GET /page?x HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n";
        let none = answer(Config::default(), request).await;
        assert!(none.starts_with("HTTP/1.1 404 "), "{none}");
        let http: Http = Arc::new(|method: &str, target: &str| format!("{method} {target}").into_bytes());
        let config = Config {
            http: Some(http),
            ..Config::default()
        };
        assert_eq!(answer(config, request).await, "GET /page?x");
    }
}
