//! A session whose command is pending keeps reading: pings are answered at
//! once, a close is answered at once (the command still ends), later
//! requests wait in a bounded backlog and are answered in order after it.
//! lluavd's connection code over a real socket, with a handler that waits
//! the way a backend answering `Outcome::Pending` makes the protocol
//! handler wait (the MAVLink backend's own test is tests/mavlink's
//! test_keepalive.py).

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use futures_util::{SinkExt, Stream, StreamExt};
use lluav_core::{Message as Incoming, Outcome};
use lluav_host::net::waiting::MAX_BACKLOG;
use lluav_host::net::{self, Handler, Limits};
use lluav_tests::{Conn, Received, WAIT};
use tokio::net::{TcpListener, TcpSocket};
use tokio::sync::{Semaphore, oneshot};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::protocol::frame::Frame;
use tokio_tungstenite::tungstenite::protocol::frame::coding::{Data, OpCode};

/// Echoes every text message and otherwise follows the core's close
/// policy (binary 1003, invalid text 1007, oversized 1009), as lluavd's
/// handlers do; a message starting with `wait` is answered only once the
/// test releases it.
struct Waits {
    release: Semaphore,
    /// Waiting messages that got to their end (answered or not).
    finished: AtomicUsize,
}

impl Handler for Waits {
    type Session = ();

    fn session(&self, _: SocketAddr) {}

    fn admitted(&self, _: &()) -> bool {
        true
    }

    async fn handle<'o>(&'o self, _: &'o mut (), message: Incoming<'o>, _: &'o mut [u8]) -> Outcome<'o> {
        let text = match message.text() {
            Ok(text) => text,
            Err(code) => return Outcome::Close(code),
        };
        if text.starts_with("wait") {
            if let Ok(permit) = self.release.acquire().await {
                permit.forget();
            }
            self.finished.fetch_add(1, Ordering::SeqCst);
        }
        Outcome::Reply(text)
    }
}

/// A server with the [`Waits`] handler and `limits`.
struct Server {
    addr: SocketAddr,
    url: String,
    handler: Arc<Waits>,
    _stop: oneshot::Sender<()>,
}

async fn server(limits: Limits) -> Server {
    let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
    let addr = listener.local_addr().expect("address");
    let url = format!("ws://{addr}");
    let handler = Arc::new(Waits {
        release: Semaphore::new(0),
        finished: AtomicUsize::new(0),
    });
    let (stop, stopped) = oneshot::channel::<()>();
    let config = net::Config {
        limits,
        ..net::Config::default()
    };
    tokio::spawn(net::serve(listener, Arc::clone(&handler), config, async {
        let _ = stopped.await;
    }));
    Server {
        addr,
        url,
        handler,
        _stop: stop,
    }
}

async fn ping(c: &mut Conn, payload: &[u8]) {
    c.send_raw(Message::Ping(payload.to_vec().into())).await;
}

fn text(s: &str) -> Received {
    Received::Text(s.into())
}

/// The next message of `stream`, which must be a text message.
async fn next_text<E: std::fmt::Debug>(
    stream: &mut (impl Stream<Item = Result<Message, E>> + Unpin),
) -> String {
    let got = tokio::time::timeout(WAIT, stream.next())
        .await
        .expect("an answer in time");
    match got {
        Some(Ok(Message::Text(t))) => t.as_str().to_owned(),
        other => panic!("expected a text message, got {other:?}"),
    }
}

/// Nothing arrives for a while (long enough for a server that reads on to
/// have answered): a wrong implementation fails it, a slow machine does not.
async fn nothing_arrives(c: &mut Conn) {
    let got = tokio::time::timeout(Duration::from_millis(500), c.recv()).await;
    assert!(got.is_err(), "nothing expected yet, got {:?}", got.ok());
}

#[tokio::test]
async fn pings_are_answered_while_a_command_waits() {
    let s = server(Limits::default()).await;
    let mut c = Conn::connect(&s.url).await;
    c.send("wait").await;
    for n in 0..3u8 {
        ping(&mut c, &[n]).await;
        // The command has not been released: this pong came while it waited.
        assert_eq!(c.recv().await, Received::Pong(vec![n]));
    }
    s.handler.release.add_permits(1);
    assert_eq!(c.recv().await, text("wait"));
}

#[tokio::test]
async fn requests_sent_during_a_wait_are_answered_after_it_in_order() {
    let s = server(Limits::default()).await;
    let mut c = Conn::connect(&s.url).await;
    c.send("wait 1").await;
    c.send("a").await;
    c.send("wait 2").await;
    c.send("b").await;
    ping(&mut c, b"behind").await;
    assert_eq!(
        c.recv().await,
        Received::Pong(b"behind".to_vec()),
        "read past the requests"
    );
    s.handler.release.add_permits(1);
    assert_eq!(c.recv().await, text("wait 1"));
    assert_eq!(c.recv().await, text("a"));
    // The second wait is a queued request's: the session reads on again.
    ping(&mut c, b"again").await;
    assert_eq!(c.recv().await, Received::Pong(b"again".to_vec()));
    c.send("c").await;
    s.handler.release.add_permits(1);
    for want in ["wait 2", "b", "c"] {
        assert_eq!(c.recv().await, text(want));
    }
}

#[tokio::test]
async fn replies_to_requests_before_a_wait_are_not_held_up_by_it() {
    let s = server(Limits::default()).await;
    let (mut ws, _) = tokio_tungstenite::connect_async(&s.url).await.expect("connect");
    // Written together, so that lluavd queues the first reply and finds
    // the second request before it writes.
    ws.feed(Message::text("first")).await.expect("send");
    ws.feed(Message::text("wait")).await.expect("send");
    ws.flush().await.expect("send");
    assert_eq!(next_text(&mut ws).await, "first");
    s.handler.release.add_permits(1);
    assert_eq!(next_text(&mut ws).await, "wait");
}

#[tokio::test]
async fn a_close_during_a_wait_is_answered_at_once_and_the_command_still_ends() {
    let s = server(Limits::default()).await;
    let mut c = Conn::connect(&s.url).await;
    c.send("wait").await;
    c.send("never run").await;
    c.send_raw(Message::Close(None)).await;
    assert_eq!(c.recv().await, Received::Close(Some(1000)));
    assert_eq!(s.handler.finished.load(Ordering::SeqCst), 0);
    s.handler.release.add_permits(1);
    let deadline = tokio::time::Instant::now() + WAIT;
    while s.handler.finished.load(Ordering::SeqCst) == 0 {
        assert!(tokio::time::Instant::now() < deadline, "the command never ended");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

#[tokio::test]
async fn reading_stops_when_the_backlog_holds_its_most_messages() {
    let s = server(Limits::default()).await;
    let mut c = Conn::connect(&s.url).await;
    c.send("wait").await;
    let requests: Vec<String> = (0..MAX_BACKLOG + 8).map(|n| format!("r{n}")).collect();
    for r in &requests {
        c.send(r).await;
    }
    ping(&mut c, b"beyond").await;
    nothing_arrives(&mut c).await;
    s.handler.release.add_permits(1);
    assert_eq!(c.recv().await, text("wait"));
    for r in &requests {
        assert_eq!(c.recv().await, text(r));
    }
    assert_eq!(
        c.recv().await,
        Received::Pong(b"beyond".to_vec()),
        "answered in turn"
    );
}

#[tokio::test]
async fn a_ping_behind_the_longest_message_is_reached_but_not_one_behind_more() {
    let limits = Limits {
        max_message: 8 * 1024,
        ..Limits::default()
    };
    let s = server(limits).await;
    let mut c = Conn::connect(&s.url).await;
    let longest = "x".repeat(limits.max_message);
    c.send("wait").await;
    c.send(&longest).await;
    ping(&mut c, b"1").await;
    assert_eq!(c.recv().await, Received::Pong(b"1".to_vec()));
    c.send("y").await;
    ping(&mut c, b"2").await;
    nothing_arrives(&mut c).await;
    s.handler.release.add_permits(1);
    for want in ["wait", &longest, "y"] {
        assert_eq!(c.recv().await, text(want));
    }
    assert_eq!(c.recv().await, Received::Pong(b"2".to_vec()));
}

/// `bad`, sent behind a waiting command and a request, closes the session
/// with `code` once the command and the request are answered. A message
/// the handler refuses (`read_past`) is a message like any other while
/// the command waits: the ping behind it is answered; behind one the
/// reader fails, nothing is read.
async fn ends_the_session_at_its_turn(bad: Message, read_past: bool, code: u16) {
    let limits = Limits {
        max_message: 8 * 1024,
        ..Limits::default()
    };
    let s = server(limits).await;
    let mut c = Conn::connect(&s.url).await;
    c.send("wait").await;
    c.send("before").await;
    c.send_raw(bad).await;
    c.send("after").await;
    ping(&mut c, b"after").await;
    if read_past {
        assert_eq!(c.recv().await, Received::Pong(b"after".to_vec()));
    } else {
        nothing_arrives(&mut c).await;
    }
    s.handler.release.add_permits(1);
    assert_eq!(c.recv().await, text("wait"));
    assert_eq!(c.recv().await, text("before"));
    assert_eq!(c.close_code().await, Some(code));
}

#[tokio::test]
async fn a_binary_message_read_during_a_wait_closes_at_its_turn() {
    // The handler's close (the core's policy), not the reader's.
    ends_the_session_at_its_turn(Message::Binary(vec![1, 2, 3].into()), true, 1003).await;
}

#[tokio::test]
async fn an_oversized_message_read_during_a_wait_closes_at_its_turn() {
    ends_the_session_at_its_turn(Message::text("x".repeat(8 * 1024 + 1)), false, 1009).await;
}

#[tokio::test]
async fn invalid_text_read_during_a_wait_closes_at_its_turn() {
    // The first piece of a message that can never be valid UTF-8: the
    // reader fails it there, before its end.
    let piece = Frame::message(b"ok \xff".to_vec(), OpCode::Data(Data::Text), false);
    ends_the_session_at_its_turn(Message::Frame(piece), false, 1007).await;
}

#[tokio::test]
async fn nothing_after_a_message_that_ends_the_session_is_read_by_a_later_wait() {
    let s = server(Limits::default()).await;
    let mut c = Conn::connect(&s.url).await;
    c.send("wait 1").await;
    c.send("wait 2").await;
    c.send_text_frame(b"\xff", Data::Text, false).await;
    s.handler.release.add_permits(1);
    assert_eq!(c.recv().await, text("wait 1"));
    // `wait 2` waits now, queued before the invalid text: its wait reads
    // nothing, so neither this ping nor this close is answered before the
    // session ends with 1007.
    ping(&mut c, b"late").await;
    c.send_raw(Message::Close(None)).await;
    nothing_arrives(&mut c).await;
    s.handler.release.add_permits(1);
    assert_eq!(c.recv().await, text("wait 2"));
    assert_eq!(c.recv().await, Received::Close(Some(1007)));
}

#[tokio::test]
async fn a_client_that_keeps_sending_during_a_wait_meets_back_pressure() {
    /// Bytes of each message: 4 KiB, the most lluavd reads at once.
    const SIZE: usize = 4096;
    /// Messages the client tries to send: 32 MiB, more than the kernel
    /// buffers of an unread connection take.
    const TOTAL: usize = 8192;
    /// Most bytes the client may have handed on when lluavd stops reading:
    /// lluavd's backlog (twice the message limit at most) and read buffer,
    /// the socket buffers of both ends (the client's fixed, so the kernel
    /// does not grow it to megabytes) and the client's write buffer. An
    /// unbounded backlog would take all of TOTAL.
    const BOUND: usize = 2 << 20;
    let s = server(Limits::default()).await;
    let socket = TcpSocket::new_v4().expect("socket");
    socket.set_send_buffer_size(64 * 1024).expect("SO_SNDBUF");
    let tcp = socket.connect(s.addr).await.expect("connect");
    let (ws, _) = tokio_tungstenite::client_async(s.url.as_str(), tcp)
        .await
        .expect("upgrade");
    let (mut sink, mut stream) = ws.split();
    sink.send(Message::text("wait")).await.expect("send");
    let sent = Arc::new(AtomicUsize::new(0));
    let writer = tokio::spawn({
        let sent = Arc::clone(&sent);
        async move {
            for n in 0..TOTAL {
                sink.send(Message::text(format!("{n:0SIZE$}")))
                    .await
                    .expect("send");
                sent.store(n + 1, Ordering::SeqCst);
            }
            sink
        }
    });
    // Sending stalls: lluavd stopped reading.
    let mut before = 0;
    loop {
        tokio::time::sleep(Duration::from_secs(1)).await;
        let now = sent.load(Ordering::SeqCst);
        assert!(
            now < TOTAL,
            "lluavd read all {TOTAL} messages while the command waited"
        );
        if now == before {
            break;
        }
        before = now;
    }
    assert!(
        before * SIZE < BOUND,
        "{} bytes taken before sending stalled",
        before * SIZE
    );
    s.handler.release.add_permits(1);
    assert_eq!(next_text(&mut stream).await, "wait");
    for n in 0..TOTAL {
        assert_eq!(
            next_text(&mut stream).await,
            format!("{n:0SIZE$}"),
            "the reply to message {n}"
        );
    }
    let _sink = writer.await.expect("the writer");
}

#[tokio::test]
async fn the_idle_timeout_counts_from_the_end_of_a_wait() {
    // Long enough that a loaded machine cannot take that long between the
    // answer and the next message; the wait outlasts it by half.
    let limits = Limits {
        idle_timeout: Duration::from_secs(4),
        ..Limits::default()
    };
    let s = server(limits).await;
    let mut c = Conn::connect(&s.url).await;
    c.send("wait").await;
    tokio::time::sleep(Duration::from_secs(6)).await;
    s.handler.release.add_permits(1);
    assert_eq!(c.recv().await, text("wait"));
    c.send("still here").await;
    assert_eq!(c.recv().await, text("still here"), "not closed as idle");
    assert_eq!(c.close_code().await, Some(1000), "idle after the answer");
}
