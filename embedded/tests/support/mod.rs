//! Test support: a thread-parking executor, embassy-net stacks joined by
//! an in-memory Ethernet hub (the adapter's and [`CLIENTS`] clients', each
//! with its own address), a minimal WebSocket client and a small vehicle
//! backend.
#![allow(dead_code)]

mod executor;

pub use executor::block_on;

use std::future::Future;
use std::task::Poll;

use embassy_futures::join::join;
use embassy_futures::select::{Either, select};
use embassy_net::tcp::TcpSocket;
use embassy_net::{Config as NetConfig, Ipv4Address, Ipv4Cidr, Stack, StackResources, StaticConfigV4};
use embassy_net_driver_channel::{self as ch, driver::HardwareAddress, driver::LinkState};
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_time::{Duration, Timer, with_timeout};
use lluav_core::{
    Args, Auth, Backend, Command, CommandId, Context as Ctx, Failure, Fields, Server, Step, Ticket,
};
use lluav_embedded::{Config, Service, SharedServer, Slot, serve};

pub const SERVER_IP: Ipv4Address = Ipv4Address::new(10, 53, 0, 1);
pub const CLIENT_IP: Ipv4Address = Ipv4Address::new(10, 53, 0, 2);
pub const PASSWORD: &str = "secret";
/// Generous: only a hung adapter ever reaches it.
pub const TEST_TIMEOUT: Duration = Duration::from_secs(60);
/// Client stacks on the hub, at 10.53.0.2, 10.53.0.3, ...
pub const CLIENTS: usize = 4;

const MTU: usize = 1514;
type Link = ch::State<MTU, 8, 8>;

/// Frame limit of the adapter under test.
pub const FRAME: usize = 4096;
/// Reply capacity of the adapter under test.
pub const OUT: usize = 2048;
/// Concurrent sessions of the adapter under test.
pub const SESSIONS: usize = 4;
/// The firmware's slot.
pub type TestSlot = Slot<1024, 2304, FRAME, OUT>;

fn leak<T>(value: T) -> &'static mut T {
    Box::leak(Box::new(value))
}

/// The address of client `i`.
pub fn client_ip(i: usize) -> Ipv4Address {
    Ipv4Address::new(10, 53, 0, 2 + i as u8)
}

/// Copies every frame a device transmits to every other device (smoltcp
/// drops frames for other MACs).
async fn hub<const D: usize>(
    tx: &mut [ch::TxRunner<'static, MTU>; D],
    rx: &mut [ch::RxRunner<'static, MTU>; D],
) {
    loop {
        let (from, packet) = core::future::poll_fn(|cx| {
            for (i, t) in tx.iter_mut().enumerate() {
                if let Poll::Ready(p) = t.poll_tx_buf(cx) {
                    let packet = p.to_vec();
                    t.tx_done();
                    return Poll::Ready((i, packet));
                }
            }
            Poll::Pending
        })
        .await;
        for (i, r) in rx.iter_mut().enumerate() {
            if i != from {
                let slot = r.rx_buf().await;
                slot[..packet.len()].copy_from_slice(&packet);
                r.rx_done(packet.len());
            }
        }
    }
}

fn stack(
    mac: u8,
    ip: Ipv4Address,
    seed: u64,
) -> (
    Stack<'static>,
    embassy_net::Runner<'static, ch::Device<'static, MTU>>,
    ch::Runner<'static, MTU>,
) {
    let (runner, device) = ch::new(leak(Link::new()), HardwareAddress::Ethernet([2, 0, 0, 0, 0, mac]));
    let config = NetConfig::ipv4_static(StaticConfigV4 {
        address: Ipv4Cidr::new(ip, 24),
        gateway: None,
        dns_servers: Default::default(),
    });
    let (stack, net) = embassy_net::new(device, config, leak(StackResources::<16>::new()), seed);
    (stack, net, runner)
}

/// Runs `test` as a client on one stack against the adapter serving
/// `service` on another, within [`TEST_TIMEOUT`].
pub fn with_service<S, F, Fut>(service: S, test: F)
where
    S: Service,
    F: FnOnce(Stack<'static>) -> Fut,
    Fut: Future<Output = ()>,
{
    with_world(service, Config::new(), |clients| test(clients[0]));
}

/// Runs `test` with [`CLIENTS`] client stacks (one address each) against
/// the adapter serving `service` with `config` and [`SESSIONS`] slots,
/// within [`TEST_TIMEOUT`].
pub fn with_world<S, F, Fut>(service: S, config: Config, test: F)
where
    S: Service,
    F: FnOnce([Stack<'static>; CLIENTS]) -> Fut,
    Fut: Future<Output = ()>,
{
    // RUST_LOG=lluav_embedded=debug shows the adapter's decisions.
    let _ = env_logger::builder().is_test(true).try_init();
    let (server, mut server_net, server_link) = stack(1, SERVER_IP, 1);
    let mut clients = Vec::new();
    let mut links = vec![server_link];
    for i in 0..CLIENTS {
        let (client, net, link) = stack(2 + i as u8, client_ip(i), 2 + i as u64);
        clients.push((client, net));
        links.push(link);
    }
    let (mut rxs, mut txs) = (Vec::new(), Vec::new());
    for link in links {
        let (state, rx, tx) = link.split();
        state.set_link_state(LinkState::Up);
        rxs.push(rx);
        txs.push(tx);
    }
    let mut rxs: [_; CLIENTS + 1] = rxs.try_into().ok().unwrap();
    let mut txs: [_; CLIENTS + 1] = txs.try_into().ok().unwrap();
    let stacks: [Stack<'static>; CLIENTS] = core::array::from_fn(|i| clients[i].0);
    let nets = embassy_futures::join::join_array(
        <[_; CLIENTS]>::try_from(clients.into_iter().map(|(_, net)| net).collect::<Vec<_>>())
            .ok()
            .unwrap()
            .map(|mut net| async move { net.run().await }),
    );
    let slots = leak([const { TestSlot::new() }; SESSIONS]);
    let world = join(
        join(server_net.run(), nets),
        join(hub(&mut txs, &mut rxs), serve(server, &config, &service, slots)),
    );
    let body = with_timeout(TEST_TIMEOUT, test(stacks));
    match block_on(select(world, body)) {
        Either::First(_) => unreachable!("the network never stops"),
        Either::Second(result) => result.expect("the test timed out"),
    }
}

/// Runs futures concurrently until all are done.
pub async fn join_all<F: Future<Output = ()>>(futures: impl IntoIterator<Item = F>) {
    let mut futures: Vec<_> = futures.into_iter().map(Box::pin).collect();
    core::future::poll_fn(|cx| {
        futures.retain_mut(|f| f.as_mut().poll(cx).is_pending());
        if futures.is_empty() {
            Poll::Ready(())
        } else {
            Poll::Pending
        }
    })
    .await;
}

/// The protocol server with [`Vehicle`] and password [`PASSWORD`].
pub fn protocol_server() -> SharedServer<NoopRawMutex, Vehicle, fn() -> i64> {
    let server = Server::new(
        Vehicle::default(),
        (|| 1_714_233_600_000) as fn() -> i64,
        Auth::new(Some(PASSWORD)).unwrap(),
    );
    SharedServer::new(server)
}

/// Runs `test` against the protocol server with [`Vehicle`] and password [`PASSWORD`].
pub fn with_server<F, Fut>(test: F)
where
    F: FnOnce(Stack<'static>) -> Fut,
    Fut: Future<Output = ()>,
{
    with_service(protocol_server(), test)
}

/// A vehicle that arms on `takeoff` and disarms on `land`/`disarm`.
/// `takeoff` waits for its autopilot like a real one: it answers pending,
/// and is still pending the first [`TAKEOFF_POLLS`] times it is asked again.
#[derive(Default)]
pub struct Vehicle {
    armed: bool,
    /// How many more times a pending takeoff answers pending.
    takeoff_polls: u32,
}

/// How often a pending `takeoff` is still pending when asked again (at the
/// adapter's 5 ms poll, about 100 ms).
pub const TAKEOFF_POLLS: u32 = 20;

impl Backend for Vehicle {
    fn armed(&self) -> bool {
        self.armed
    }

    fn execute(&mut self, cmd: &Command<'_>, ctx: &Ctx, out: &mut Fields<'_>) -> Result<Step, Failure> {
        match (cmd.id(), cmd.args()) {
            (CommandId::Takeoff, _) => {
                self.takeoff_polls = TAKEOFF_POLLS;
                return Ok(Step::Pending(Ticket(7)));
            }
            (CommandId::Land | CommandId::Disarm, _) => self.armed = false,
            (CommandId::State, _) => {
                let armed = self.armed;
                out.object("state", |s| {
                    s.bool("armed", armed)
                        .str("fsm", if armed { "armed" } else { "disarmed" })
                        .bool("lock_mode", ctx.lock_mode);
                });
            }
            (CommandId::Ledpwm, Args::Pwm(v)) => {
                out.u64("pwm", u64::from(*v));
            }
            _ => return Err(Failure::unsupported("not in the test vehicle")),
        }
        Ok(Step::Done)
    }

    fn finish(&mut self, ticket: Ticket, _: &Ctx, out: &mut Fields<'_>) -> Result<Step, Failure> {
        assert_eq!(ticket, Ticket(7), "only takeoff pends");
        if self.takeoff_polls > 0 {
            self.takeoff_polls -= 1;
            return Ok(Step::Pending(ticket));
        }
        self.armed = true;
        out.bool("armed", true);
        Ok(Step::Done)
    }
}

/// An opcode as a client sends it.
pub mod op {
    pub const CONTINUATION: u8 = 0;
    pub const TEXT: u8 = 1;
    pub const BINARY: u8 = 2;
    pub const CLOSE: u8 = 8;
    pub const PING: u8 = 9;
    pub const PONG: u8 = 10;
}

/// The RFC 6455 example key and its accept value.
pub const KEY: &str = "dGhlIHNhbXBsZSBub25jZQ==";
pub const ACCEPT: &str = "s3pPLMBiTxaQ9kYGzzhZRbK+xOo=";

pub fn upgrade_request(extra: &str) -> String {
    upgrade_request_to(&format!("{SERVER_IP}:53001"), extra)
}

/// An upgrade request with the RFC example key whose `Host` is `host`.
pub fn upgrade_request_to(host: &str, extra: &str) -> String {
    format!(
        "GET / HTTP/1.1\r\nHost: {host}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\n{extra}\r\n"
    )
}

/// A frame as the client received it.
#[derive(Debug, PartialEq, Eq)]
pub struct Frame {
    pub fin: bool,
    pub opcode: u8,
    pub payload: Vec<u8>,
}

impl Frame {
    pub fn text(&self) -> serde_json::Value {
        assert_eq!((self.fin, self.opcode), (true, op::TEXT), "{self:?}");
        serde_json::from_slice(&self.payload).expect("a JSON response")
    }

    pub fn close_code(&self) -> u16 {
        assert_eq!(self.opcode, op::CLOSE, "{self:?}");
        u16::from_be_bytes([self.payload[0], self.payload[1]])
    }
}

/// A minimal WebSocket client over the client stack.
pub struct Client {
    socket: TcpSocket<'static>,
    inbox: Vec<u8>,
}

impl Client {
    /// Opens a TCP connection to the adapter.
    pub async fn tcp(stack: Stack<'static>) -> Client {
        Client::try_tcp(stack).await.expect("connect")
    }

    /// Opens a TCP connection to the adapter, if it accepts one.
    pub async fn try_tcp(stack: Stack<'static>) -> Result<Client, embassy_net::tcp::ConnectError> {
        Client::try_tcp_with(stack, 8192).await
    }

    /// Opens a TCP connection with `buffer`-byte socket buffers (attackers
    /// open many, and their buffers are leaked).
    pub async fn try_tcp_with(
        stack: Stack<'static>,
        buffer: usize,
    ) -> Result<Client, embassy_net::tcp::ConnectError> {
        let rx = Box::leak(vec![0; buffer].into_boxed_slice());
        let tx = Box::leak(vec![0; buffer].into_boxed_slice());
        let mut socket = TcpSocket::new(stack, rx, tx);
        socket.connect((SERVER_IP, lluav_embedded::PORT)).await?;
        Ok(Client {
            socket,
            inbox: Vec::new(),
        })
    }

    /// Connects and upgrades as a patient operator would: a refused or
    /// reset attempt is retried after a short pause.
    pub async fn connect_retrying(stack: Stack<'static>) -> Client {
        loop {
            if let Ok(mut client) = Client::try_tcp(stack).await {
                let request = upgrade_request(&format!("Sec-WebSocket-Key: {KEY}\r\n"));
                match client.try_request(&request).await {
                    Some(head) if head.starts_with("HTTP/1.1 101 ") => return client,
                    Some(head) => panic!("the upgrade was refused: {head}"),
                    None => {}
                }
            }
            Timer::after_millis(20).await;
        }
    }

    /// Sends bytes without waiting for them to be acknowledged; false if
    /// the connection is gone.
    pub async fn try_raw(&mut self, bytes: &[u8]) -> bool {
        embedded_io_async::Write::write_all(&mut self.socket, bytes)
            .await
            .is_ok()
    }

    /// Waits until the server ends the connection (close, reset or its
    /// TCP timeout), discarding whatever it sends.
    pub async fn wait_until_dropped(&mut self) {
        while self.more().await {
            self.inbox.clear();
        }
    }

    /// Connects and upgrades with the RFC example key, checking the accept value.
    pub async fn connect(stack: Stack<'static>) -> Client {
        let mut client = Client::tcp(stack).await;
        let head = client
            .request(&upgrade_request(&format!("Sec-WebSocket-Key: {KEY}\r\n")))
            .await;
        assert!(head.starts_with("HTTP/1.1 101 "), "{head}");
        assert!(
            head.contains(&format!("Sec-WebSocket-Accept: {ACCEPT}\r\n")),
            "{head}"
        );
        client
    }

    /// Sends raw bytes.
    pub async fn raw(&mut self, bytes: &[u8]) {
        embedded_io_async::Write::write_all(&mut self.socket, bytes)
            .await
            .expect("write");
        self.socket.flush().await.expect("flush");
    }

    /// Sends an upgrade request; returns the response head.
    pub async fn request(&mut self, request: &str) -> String {
        self.try_request(request)
            .await
            .expect("closed before the response head")
    }

    /// Sends an upgrade request; returns the response head, or `None` if
    /// the connection ended first.
    pub async fn try_request(&mut self, request: &str) -> Option<String> {
        if !self.try_raw(request.as_bytes()).await {
            return None;
        }
        loop {
            if let Some(end) = self.inbox.windows(4).position(|w| w == b"\r\n\r\n") {
                let head: Vec<u8> = self.inbox.drain(..end + 4).collect();
                return Some(String::from_utf8(head).expect("an ASCII head"));
            }
            if !self.more().await {
                return None;
            }
        }
    }

    /// Reads more bytes; false at end of stream.
    async fn more(&mut self) -> bool {
        let mut buf = [0; 2048];
        match self.socket.read(&mut buf).await {
            Ok(0) | Err(_) => false,
            Ok(n) => {
                self.inbox.extend_from_slice(&buf[..n]);
                true
            }
        }
    }

    /// Sends one masked frame.
    pub async fn frame(&mut self, fin: bool, opcode: u8, payload: &[u8]) {
        self.raw(&masked(fin, opcode, payload)).await;
    }

    /// Sends a text message in one frame.
    pub async fn send(&mut self, text: &str) {
        self.frame(true, op::TEXT, text.as_bytes()).await;
    }

    /// Sends `text` and returns the JSON response.
    pub async fn call(&mut self, text: &str) -> serde_json::Value {
        self.send(text).await;
        self.recv().await.text()
    }

    /// Receives one frame.
    pub async fn recv(&mut self) -> Frame {
        loop {
            if let Some((frame, used)) = parse_server_frame(&self.inbox) {
                self.inbox.drain(..used);
                return frame;
            }
            assert!(self.more().await, "closed before a whole frame");
        }
    }

    /// Whether the server closed the TCP connection (after any pending
    /// frames); if so, closes our side too, as a real client would.
    pub async fn closed(&mut self) -> bool {
        let closed = !self.more().await && self.inbox.is_empty();
        if closed {
            self.socket.close();
            let _ = self.socket.flush().await;
        }
        closed
    }

    /// Completes a close handshake we started.
    pub async fn close(mut self, code: u16) -> u16 {
        self.frame(true, op::CLOSE, &code.to_be_bytes()).await;
        let answer = self.recv().await.close_code();
        assert!(
            self.closed().await,
            "the server closes TCP after the close handshake"
        );
        answer
    }
}

/// A masked client frame.
pub fn masked(fin: bool, opcode: u8, payload: &[u8]) -> Vec<u8> {
    let mask = [0x12, 0x34, 0x56, 0x78];
    let mut out = vec![u8::from(fin) << 7 | opcode];
    match payload.len() {
        n @ 0..=125 => out.push(0x80 | n as u8),
        n @ 126..=0xffff => {
            out.push(0x80 | 126);
            out.extend_from_slice(&(n as u16).to_be_bytes());
        }
        n => {
            out.push(0x80 | 127);
            out.extend_from_slice(&(n as u64).to_be_bytes());
        }
    }
    out.extend_from_slice(&mask);
    out.extend(payload.iter().enumerate().map(|(i, b)| b ^ mask[i % 4]));
    out
}

/// Parses one unmasked server frame; `None` when incomplete.
pub fn parse_server_frame(buf: &[u8]) -> Option<(Frame, usize)> {
    let (&b0, &b1) = (buf.first()?, buf.get(1)?);
    assert_eq!(b1 & 0x80, 0, "server frames are unmasked");
    let (len, at) = match b1 & 0x7f {
        126 => (u16::from_be_bytes(buf.get(2..4)?.try_into().ok()?) as usize, 4),
        127 => (u64::from_be_bytes(buf.get(2..10)?.try_into().ok()?) as usize, 10),
        n => (n as usize, 2),
    };
    let payload = buf.get(at..at + len)?.to_vec();
    Some((
        Frame {
            fin: b0 & 0x80 != 0,
            opcode: b0 & 0x0f,
            payload,
        },
        at + len,
    ))
}
