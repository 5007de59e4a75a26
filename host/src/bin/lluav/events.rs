//! `lluav events [--json] [--reconnect]`: follows the server's `/events`
//! stream (DESIGN.md, "Events"), one line per event, until Ctrl-C.
//!
//! What an operator watching a flight needs from it: every line safe for
//! the terminal (`lluav_host::terminal`); a gap said as a gap; and no
//! silent end — a refused login, or a connection that ends, is said on
//! stderr and exits 1, so that a script or a shell loop sees it. With
//! `--reconnect` the stream goes on across a dropped network or a restart
//! of lluavd, and stderr says what may have been missed (events are not
//! kept for a client that was away: the count comes from `seq`, and a new
//! `boot` means the daemon restarted and its count started over). A wrong
//! password is never tried again: it counts towards the lockout.

use std::io::Write;
use std::process::ExitCode;
use std::time::Duration;

use lluav_host::client::{ClientError, ConnectOptions, Events, events_url};
use lluav_host::terminal::{escape, event_line, json_line};
use serde_json::{Map, Value};
use tokio::runtime::Runtime;
use tokio::signal::unix::{SignalKind, signal};

use super::Cli;

/// How long one connection attempt, login included, may take.
const CONNECT_WAIT: Duration = Duration::from_secs(10);

/// Pauses before reconnecting, growing with each failure in a row.
const RECONNECT_PAUSES: [Duration; 6] = [
    Duration::from_millis(500),
    Duration::from_secs(1),
    Duration::from_secs(2),
    Duration::from_secs(4),
    Duration::from_secs(8),
    Duration::from_secs(10),
];

/// How long a clean close may take once Ctrl-C was pressed.
const CLOSE_WAIT: Duration = Duration::from_secs(1);

/// `lluav events`, with `--json` and `--reconnect` before or after it.
pub fn follow(runtime: &Runtime, mut cli: Cli) -> ExitCode {
    for arg in cli.command.iter().skip(1) {
        match arg.as_str() {
            "--json" => cli.json = true,
            "--reconnect" => cli.reconnect = true,
            other => {
                eprintln!(
                    "lluav: `events` takes --json and --reconnect, not `{}`; usage: lluav [--url URL] [--password P] events [--json] [--reconnect]",
                    escape(other)
                );
                return ExitCode::from(2);
            }
        }
    }
    runtime.block_on(follow_events(&cli))
}

/// What the last connection saw: to tell, after a reconnect, what was
/// missed.
#[derive(Default)]
struct Seen {
    /// The `boot` and `seq` of the last event printed.
    last: Option<(String, u64)>,
    /// Whether the next event is the first of a new connection.
    reconnected: bool,
}

/// Why one connection ended.
enum Ended {
    /// Ctrl-C: the person is done.
    Interrupted,
    /// stdout is gone (`lluav events | head`): nothing more to do.
    StdoutClosed,
    /// Printing failed otherwise.
    StdoutFailed(std::io::Error),
    /// The connection could not be made, was refused, or ended.
    Failed(ClientError),
}

async fn follow_events(cli: &Cli) -> ExitCode {
    let mut interrupt = match signal(SignalKind::interrupt()) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("lluav: cannot catch Ctrl-C: {e}");
            return ExitCode::FAILURE;
        }
    };
    let url = events_url(&cli.url);
    let mut seen = Seen::default();
    let mut failures = 0usize;
    loop {
        let ended = once(cli, &url, &mut seen, &mut failures, &mut interrupt).await;
        let e = match ended {
            Ended::Interrupted | Ended::StdoutClosed => return ExitCode::SUCCESS,
            Ended::StdoutFailed(e) => {
                eprintln!("lluav: cannot print the events: {e}");
                return ExitCode::FAILURE;
            }
            Ended::Failed(e) => e,
        };
        let said = escape(&e.to_string()).into_owned();
        let hint = hint(&e, cli);
        if !cli.reconnect || !worth_retrying(&e) {
            eprintln!("lluav: events from {url}: {said}{hint}");
            return ExitCode::FAILURE;
        }
        let pause = RECONNECT_PAUSES[failures.min(RECONNECT_PAUSES.len() - 1)];
        failures += 1;
        eprintln!(
            "lluav: events from {url}: {said}; reconnecting in {:.1} s",
            pause.as_secs_f64()
        );
        tokio::select! {
            _ = interrupt.recv() => return ExitCode::SUCCESS,
            () = tokio::time::sleep(pause) => {}
        }
        seen.reconnected = seen.last.is_some();
    }
}

/// One connection: subscribes, then prints every event until it ends.
async fn once(
    cli: &Cli,
    url: &str,
    seen: &mut Seen,
    failures: &mut usize,
    interrupt: &mut tokio::signal::unix::Signal,
) -> Ended {
    let options = ConnectOptions {
        ca_file: cli.cafile.clone(),
    };
    let subscribing = tokio::time::timeout(
        CONNECT_WAIT,
        Events::subscribe(&cli.url, &options, cli.password.as_deref()),
    );
    let mut events = tokio::select! {
        _ = interrupt.recv() => return Ended::Interrupted,
        subscribed = subscribing => match subscribed {
            Ok(Ok(events)) => events,
            Ok(Err(e)) => return Ended::Failed(e),
            Err(_) => return Ended::Failed(timed_out(url)),
        },
    };
    *failures = 0;
    // On stderr, so that stdout stays the events alone (`--json` lines).
    eprintln!("lluav: following the events of {url}; Ctrl-C stops");
    let mut out = std::io::stdout();
    loop {
        let event = tokio::select! {
            _ = interrupt.recv() => {
                let _ = tokio::time::timeout(CLOSE_WAIT, events.close()).await;
                return Ended::Interrupted;
            }
            next = events.next() => match next {
                Ok(event) => event,
                Err(e) => return Ended::Failed(e),
            },
        };
        note_missed(seen, &event);
        let line = if cli.json {
            json_line(&Value::Object(event))
        } else {
            event_line(&event)
        };
        // One write per line, flushed: a pipe gets each event at once.
        if let Err(e) = writeln!(out, "{line}").and_then(|()| out.flush()) {
            return if e.kind() == std::io::ErrorKind::BrokenPipe {
                Ended::StdoutClosed
            } else {
                Ended::StdoutFailed(e)
            };
        }
    }
}

/// After a reconnect, says on stderr what the stream did not bring; keeps
/// the last `boot` and `seq` seen.
fn note_missed(seen: &mut Seen, event: &Map<String, Value>) {
    let (Some(boot), Some(seq)) = (
        event.get("boot").and_then(Value::as_str),
        event.get("seq").and_then(Value::as_u64),
    ) else {
        // A gap: the server says itself how many were missed.
        return;
    };
    if std::mem::take(&mut seen.reconnected)
        && let Some((last_boot, last_seq)) = &seen.last
    {
        if last_boot != boot {
            eprintln!(
                "lluav: lluavd restarted while this client was away (boot {} is new; seq counts from 1 again): events after #{last_seq} of the previous run and before #{seq} of this one were missed",
                escape(boot)
            );
        } else if seq > last_seq + 1 {
            eprintln!(
                "lluav: {} events missed while reconnecting (#{} to #{})",
                seq - last_seq - 1,
                last_seq + 1,
                seq - 1
            );
        }
    }
    seen.last = Some((boot.to_owned(), seq));
}

fn timed_out(url: &str) -> ClientError {
    use tokio_tungstenite::tungstenite::Error as WsError;
    let why = format!("no connection within {} s", CONNECT_WAIT.as_secs());
    ClientError::Connect {
        url: url.to_owned(),
        source: Box::new(WsError::Io(std::io::Error::new(
            std::io::ErrorKind::TimedOut,
            why,
        ))),
    }
}

/// Whether another connection may fare better: a network or a daemon that
/// went away, not a refusal (a wrong password, a login that was due, a
/// certificate, a URL, a server that is not lluavd).
fn worth_retrying(e: &ClientError) -> bool {
    use tokio_tungstenite::tungstenite::Error as WsError;
    match e {
        ClientError::Connect { source, .. } => match &**source {
            WsError::Io(io) => !io.to_string().contains("certificate"),
            WsError::Http(response) => response.status().is_server_error(),
            WsError::ConnectionClosed | WsError::AlreadyClosed | WsError::Protocol(_) => true,
            _ => false,
        },
        ClientError::Transport(_) => true,
        // 1001: lluavd stops; 1006: no close frame; 1011-1013: the
        // server's trouble. 1008 is a policy (no login, too many wrong
        // passwords): trying again changes nothing.
        ClientError::Closed { code, .. } => matches!(code, None | Some(1001 | 1006 | 1011..=1013)),
        _ => false,
    }
}

/// What to do about `e`, when there is something to say.
fn hint(e: &ClientError, cli: &Cli) -> &'static str {
    use tokio_tungstenite::tungstenite::Error as WsError;
    match e {
        ClientError::Closed { code: Some(1008), .. } if cli.password.is_none() => {
            " (this vehicle has a password: --password P or LLUAV_PASSWORD)"
        }
        ClientError::Connect { source, .. } => match &**source {
            WsError::Io(io) if io.kind() == std::io::ErrorKind::ConnectionRefused => " (is lluavd running?)",
            WsError::Io(io) if io.to_string().contains("certificate") => {
                " (a self-signed server certificate needs --cafile FILE)"
            }
            _ => "",
        },
        _ if !cli.reconnect => "",
        _ => "",
    }
}

/// `lluav --broker URL events [--vehicle V[,V2...]] [--json]`: the events
/// of every vehicle (`lluav/+/events`) or of those named, one line each,
/// prefixed with the vehicle's id, until Ctrl-C.
pub fn follow_broker(runtime: &Runtime, mut cli: Cli) -> ExitCode {
    for arg in cli.command.iter().skip(1) {
        match arg.as_str() {
            "--json" => cli.json = true,
            other => {
                eprintln!(
                    "lluav: `events` through a broker takes --json, not `{}`; usage: lluav --broker URL events [--vehicle V[,V2...]] [--json]",
                    escape(other)
                );
                return ExitCode::from(2);
            }
        }
    }
    if cli.reconnect {
        eprintln!("lluav: through a broker the connection is kept by itself: no --reconnect");
        return ExitCode::from(2);
    }
    runtime.block_on(follow_broker_events(&cli))
}

async fn follow_broker_events(cli: &Cli) -> ExitCode {
    let mut interrupt = match signal(SignalKind::interrupt()) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("lluav: cannot catch Ctrl-C: {e}");
            return ExitCode::FAILURE;
        }
    };
    let fleet = match super::fleet(cli).await {
        Ok(f) => f,
        Err(e) => {
            eprintln!("lluav: {}", escape(&e.to_string()));
            return ExitCode::FAILURE;
        }
    };
    // One vehicle: its own topic; several: every vehicle's, the others
    // left out here.
    let one = match cli.vehicle.as_slice() {
        [v] => Some(v.as_str()),
        _ => None,
    };
    let mut events = match fleet.events(one).await {
        Ok(rx) => rx,
        Err(e) => {
            eprintln!("lluav: {}", escape(&e.to_string()));
            fleet.close().await;
            return ExitCode::from(2);
        }
    };
    let broker = escape(cli.broker.as_deref().unwrap_or_default()).into_owned();
    eprintln!("lluav: following the events through {broker}; Ctrl-C stops");
    let mut out = std::io::stdout();
    let code = loop {
        let (vehicle, event) = tokio::select! {
            _ = interrupt.recv() => break ExitCode::SUCCESS,
            next = events.recv() => match next {
                Some(e) => e,
                None => {
                    eprintln!("lluav: the connection to {broker} ended");
                    break ExitCode::FAILURE;
                }
            },
        };
        if !cli.vehicle.is_empty() && !cli.vehicle.contains(&vehicle) {
            continue;
        }
        let line = match event {
            Value::Object(event) if cli.json => json_line(&Value::Object(event)),
            Value::Object(event) => event_line(&event),
            _ => continue,
        };
        if let Err(e) = writeln!(out, "{}: {line}", escape(&vehicle)).and_then(|()| out.flush()) {
            if e.kind() != std::io::ErrorKind::BrokenPipe {
                eprintln!("lluav: cannot print the events: {e}");
                break ExitCode::FAILURE;
            }
            break ExitCode::SUCCESS;
        }
    };
    fleet.close().await;
    code
}
