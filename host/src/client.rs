//! A typed async client for any LLUAV server (lluavd, a board, the real
//! firmware).
//!
//! Requests are [`Command`]s, encoded by lluav-core's encoder, so a request
//! this client sends is valid by construction and every command of the
//! table is reachable through [`Client::send`] or [`Client::call`]; a few
//! common commands have typed helpers. Replies are [`Response`]s: `ret`,
//! `cmd`, `ts` and the command-specific fields.
//!
//! `ws://` and `wss://` URLs are served; for `wss://` the server's
//! certificate is checked against the system's roots, or against the CA
//! file of [`ConnectOptions::ca_file`] (a self-signed certificate).
//!
//! [`Events`] follows a server's `/events` stream (DESIGN.md, "Events"):
//! what happened to the vehicle, pushed as it happens, on a connection of
//! its own beside the command socket.
//!
//! ```no_run
//! # async fn demo() -> Result<(), lluav_host::client::ClientError> {
//! use lluav_host::client::Client;
//! let mut client = Client::connect("ws://127.0.0.1:53001").await?;
//! client.login("secret").await?.check()?;
//! let state = client.state().await?.check()?;
//! println!("{}", state.fields["state"]);
//! # Ok(()) }
//! ```

use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};

use futures_util::{SinkExt, StreamExt};
use lluav_core::{ArgError, Args, Command, CommandId, ParseError, Pose};
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, ServerName};
use serde::Deserialize;
use serde_json::{Map, Value};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpStream;
use tokio_rustls::TlsConnector;
use tokio_rustls::client::TlsStream;
use tokio_tungstenite::WebSocketStream;
use tokio_tungstenite::tungstenite::Message as WsMessage;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::protocol::WebSocketConfig;

/// The protocol's default server address.
pub const DEFAULT_URL: &str = "ws://127.0.0.1:53001";

/// One response: the three fields every response has, plus the rest.
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub struct Response {
    /// 0 on success, negative on error.
    pub ret: i64,
    /// The command's id (0 for an unknown command).
    pub cmd: i64,
    /// Server time, milliseconds since the Unix epoch.
    pub ts: i64,
    /// Command-specific fields (`msg` on errors).
    #[serde(flatten)]
    pub fields: Map<String, Value>,
}

impl Response {
    /// Whether the command succeeded (`ret == 0`).
    pub fn is_ok(&self) -> bool {
        self.ret == 0
    }

    /// The error message, if there is one.
    pub fn msg(&self) -> Option<&str> {
        self.fields.get("msg").and_then(Value::as_str)
    }

    /// The command this answers, if the id is known.
    pub fn command(&self) -> Option<CommandId> {
        u8::try_from(self.cmd).ok().and_then(CommandId::from_u8)
    }

    /// `Ok(self)` on success, [`ClientError::Failed`] when `ret < 0`.
    pub fn check(self) -> Result<Response, ClientError> {
        if self.ret < 0 {
            Err(ClientError::Failed(Box::new(self)))
        } else {
            Ok(self)
        }
    }

    /// The whole response as one JSON object, `ret`, `cmd` and `ts` first.
    pub fn to_json(&self) -> Value {
        let mut object = Map::new();
        object.insert("ret".into(), self.ret.into());
        object.insert("cmd".into(), self.cmd.into());
        object.insert("ts".into(), self.ts.into());
        object.extend(self.fields.clone());
        Value::Object(object)
    }
}

/// What went wrong talking to a server.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The WebSocket connection could not be opened.
    #[error("cannot connect to {url}: {source}")]
    Connect {
        /// The server's URL.
        url: String,
        /// Why.
        source: Box<tokio_tungstenite::tungstenite::Error>,
    },
    /// The CA file for `wss://` cannot be used.
    #[error("cannot use the CA file {path}: {why}")]
    CaFile {
        /// The file.
        path: PathBuf,
        /// Why.
        why: String,
    },
    /// TLS cannot be set up with this machine's crypto provider.
    #[error("TLS setup failed: {0}")]
    Tls(String),
    /// The connection failed while sending or receiving.
    #[error("connection lost: {0}")]
    Transport(Box<tokio_tungstenite::tungstenite::Error>),
    /// The server closed the connection instead of answering.
    #[error("the server closed the connection{}", close_detail(*.code, reason))]
    Closed {
        /// The close code, if the server sent one.
        code: Option<u16>,
        /// The close reason.
        reason: String,
    },
    /// The server answered something that is not a protocol response.
    #[error("not a protocol response ({source}): {text}")]
    BadResponse {
        /// The text received.
        text: String,
        /// Why it is not a response.
        source: serde_json::Error,
    },
    /// The arguments do not fit the command's grammar.
    #[error("invalid arguments for {}: usage: {}", .0.name(), .0.spec().usage)]
    InvalidArgs(CommandId, ArgError),
    /// A frame the client was asked to send does not parse.
    #[error("{0}")]
    Parse(String),
    /// The server sent something that is not an event on `/events`.
    #[error("not an event ({why}): {text}")]
    BadEvent {
        /// What was received (cut to its first 200 characters).
        text: String,
        /// Why it is not an event.
        why: String,
    },
    /// The command ran and failed (`ret < 0`); see [`Response::check`].
    #[error("{} failed: ret {}{}", command_name(.0), .0.ret, .0.msg().map(|m| format!(": {m}")).unwrap_or_default())]
    Failed(Box<Response>),
}

fn close_detail(code: Option<u16>, reason: &str) -> String {
    match (code, reason.is_empty()) {
        (None, _) => String::new(),
        (Some(c), true) => format!(" (code {c})"),
        (Some(c), false) => format!(" (code {c}: {reason})"),
    }
}

fn command_name(r: &Response) -> &'static str {
    r.command().map_or("command", CommandId::name)
}

/// How a [`Client`] connects.
#[derive(Clone, Debug, Default)]
pub struct ConnectOptions {
    /// A PEM file of the certificate authorities trusted for `wss://`
    /// instead of the system's: the server's own certificate, when it is
    /// self-signed.
    pub ca_file: Option<PathBuf>,
}

/// The byte stream under a client's WebSocket: plain TCP for `ws://`,
/// TLS for `wss://`.
pub enum Transport {
    /// `ws://`.
    Plain(TcpStream),
    /// `wss://`.
    Tls(Box<TlsStream<TcpStream>>),
}

impl AsyncRead for Transport {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        match self.get_mut() {
            Transport::Plain(s) => Pin::new(s).poll_read(cx, buf),
            Transport::Tls(s) => Pin::new(s.as_mut()).poll_read(cx, buf),
        }
    }
}

impl AsyncWrite for Transport {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<std::io::Result<usize>> {
        match self.get_mut() {
            Transport::Plain(s) => Pin::new(s).poll_write(cx, buf),
            Transport::Tls(s) => Pin::new(s.as_mut()).poll_write(cx, buf),
        }
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        match self.get_mut() {
            Transport::Plain(s) => Pin::new(s).poll_flush(cx),
            Transport::Tls(s) => Pin::new(s.as_mut()).poll_flush(cx),
        }
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        match self.get_mut() {
            Transport::Plain(s) => Pin::new(s).poll_shutdown(cx),
            Transport::Tls(s) => Pin::new(s.as_mut()).poll_shutdown(cx),
        }
    }
}

/// The TLS client settings for `options`: its CA file, else the system's
/// root certificates.
fn tls_connector(options: &ConnectOptions) -> Result<TlsConnector, ClientError> {
    let config = tls_config(options.ca_file.as_deref())?;
    Ok(TlsConnector::from(Arc::new(config)))
}

/// rustls client settings that trust the certificates in `ca_file` (PEM),
/// or the system's root certificates without one. The MQTT uplink and the
/// fleet client use them too.
pub fn tls_config(ca_file: Option<&Path>) -> Result<rustls::ClientConfig, ClientError> {
    let mut roots = rustls::RootCertStore::empty();
    match ca_file {
        Some(path) => {
            let bad = |why: String| ClientError::CaFile {
                path: path.to_owned(),
                why,
            };
            let certs = CertificateDer::pem_file_iter(path)
                .and_then(|certs| certs.collect::<Result<Vec<_>, _>>())
                .map_err(|e| bad(e.to_string()))?;
            if certs.is_empty() {
                return Err(bad("no CERTIFICATE block in the file".into()));
            }
            for cert in certs {
                roots.add(cert).map_err(|e| bad(e.to_string()))?;
            }
        }
        None => {
            // Certificates the system store holds but rustls cannot parse
            // are skipped, as every other client does.
            let _ = roots.add_parsable_certificates(rustls_native_certs::load_native_certs().certs);
        }
    }
    Ok(
        rustls::ClientConfig::builder_with_provider(crate::net::tls::provider())
            .with_safe_default_protocol_versions()
            .map_err(|e| ClientError::Tls(e.to_string()))?
            .with_root_certificates(roots)
            .with_no_client_auth(),
    )
}

/// Opens a WebSocket to `url` (`ws://` or `wss://`); the building block of
/// [`Client::connect_with`], for clients that speak raw frames.
pub async fn open(url: &str, options: &ConnectOptions) -> Result<WebSocketStream<Transport>, ClientError> {
    open_with_config(url, options, None).await
}

/// [`open`] with tungstenite's settings (buffer sizes, limits).
pub async fn open_with_config(
    url: &str,
    options: &ConnectOptions,
    config: Option<WebSocketConfig>,
) -> Result<WebSocketStream<Transport>, ClientError> {
    use tokio_tungstenite::tungstenite::Error as WsError;
    let failed = |e: WsError| ClientError::Connect {
        url: url.to_owned(),
        source: Box::new(e),
    };
    let io = |e: std::io::Error| failed(WsError::Io(e));
    let request = url.into_client_request().map_err(failed)?;
    let uri = request.uri();
    let tls = match uri.scheme_str() {
        Some("ws") => false,
        Some("wss") => true,
        _ => {
            return Err(failed(WsError::Url(
                tokio_tungstenite::tungstenite::error::UrlError::UnsupportedUrlScheme,
            )));
        }
    };
    let host = uri.host().unwrap_or_default();
    let host = host
        .strip_prefix('[')
        .and_then(|h| h.strip_suffix(']'))
        .unwrap_or(host)
        .to_owned();
    let port = uri.port_u16().unwrap_or(if tls { 443 } else { 80 });
    let tcp = TcpStream::connect((host.as_str(), port)).await.map_err(io)?;
    tcp.set_nodelay(true).map_err(io)?;
    let transport = if tls {
        let name = ServerName::try_from(host).map_err(|e| io(std::io::Error::other(e)))?;
        let stream = tls_connector(options)?.connect(name, tcp).await.map_err(io)?;
        Transport::Tls(Box::new(stream))
    } else {
        Transport::Plain(tcp)
    };
    let (ws, _) = tokio_tungstenite::client_async_with_config(request, transport, config)
        .await
        .map_err(failed)?;
    Ok(ws)
}

/// A connection to one server; requests are answered in order.
pub struct Client {
    ws: WebSocketStream<Transport>,
    frame: String,
}

impl Client {
    /// Connects to `url` (`ws://host:port`, or `wss://` checked against
    /// the system's root certificates).
    pub async fn connect(url: &str) -> Result<Client, ClientError> {
        Client::connect_with(url, &ConnectOptions::default()).await
    }

    /// Connects to `url` with `options` (a CA file for `wss://`).
    pub async fn connect_with(url: &str, options: &ConnectOptions) -> Result<Client, ClientError> {
        Ok(Client {
            ws: open(url, options).await?,
            frame: String::new(),
        })
    }

    /// Sends `command` and waits for its response.
    pub async fn send(&mut self, command: &Command<'_>) -> Result<Response, ClientError> {
        self.frame.clear();
        // Writing into a String cannot fail.
        let _ = command.encode(&mut self.frame);
        let frame = std::mem::take(&mut self.frame);
        let result = self.exchange(&frame).await;
        self.frame = frame;
        result
    }

    /// Builds the command `id` with `args` (checked as the server would)
    /// and sends it.
    pub async fn call(&mut self, id: CommandId, args: Args<'_>) -> Result<Response, ClientError> {
        let command = Command::new(id, args).map_err(|e| ClientError::InvalidArgs(id, e))?;
        self.send(&command).await
    }

    /// Sends a command that takes no arguments (or only optional ones).
    pub async fn bare(&mut self, id: CommandId) -> Result<Response, ClientError> {
        let args = match id.spec().grammar {
            lluav_core::Grammar::OptCount => Args::OptCount(None),
            lluav_core::Grammar::OptAmount => Args::OptAmount(None),
            lluav_core::Grammar::OptName => Args::OptName(None),
            lluav_core::Grammar::Override => Args::Override(false),
            _ => Args::None,
        };
        self.call(id, args).await
    }

    /// Parses `line` as a request (so a typo is caught before it leaves)
    /// and sends its canonical form.
    pub async fn send_line(&mut self, line: &str) -> Result<Response, ClientError> {
        let command =
            lluav_core::parse(line).map_err(|e: ParseError<'_>| ClientError::Parse(e.to_string()))?;
        self.send(&command).await
    }

    /// `login <password>`.
    pub async fn login(&mut self, password: &str) -> Result<Response, ClientError> {
        self.call(CommandId::Login, Args::Secret(password)).await
    }

    /// `state`: the vehicle's state.
    pub async fn state(&mut self) -> Result<Response, ClientError> {
        self.bare(CommandId::State).await
    }

    /// `takeoff`.
    pub async fn takeoff(&mut self) -> Result<Response, ClientError> {
        self.bare(CommandId::Takeoff).await
    }

    /// `land`.
    pub async fn land(&mut self) -> Result<Response, ClientError> {
        self.bare(CommandId::Land).await
    }

    /// `disarm`.
    pub async fn disarm(&mut self) -> Result<Response, ClientError> {
        self.bare(CommandId::Disarm).await
    }

    /// `set_sp_ned x:y:z:yaw` (NED metres, radians).
    pub async fn set_sp_ned(&mut self, pose: Pose) -> Result<Response, ClientError> {
        self.call(CommandId::SetSpNed, Args::Setpoint(pose)).await
    }

    /// `get_param name`.
    pub async fn get_param(&mut self, name: &str) -> Result<Response, ClientError> {
        self.call(CommandId::GetParam, Args::ParamName(name)).await
    }

    /// `set_param name:value`.
    pub async fn set_param(&mut self, name: &str, value: &str) -> Result<Response, ClientError> {
        self.call(CommandId::SetParam, Args::SetParam { name, value })
            .await
    }

    /// `save_param 1`: persist the parameters.
    pub async fn save_param(&mut self) -> Result<Response, ClientError> {
        self.call(CommandId::SaveParam, Args::Flag(true)).await
    }

    /// Closes the connection cleanly.
    pub async fn close(mut self) -> Result<(), ClientError> {
        self.ws
            .close(None)
            .await
            .map_err(|e| ClientError::Transport(Box::new(e)))?;
        while let Some(Ok(_)) = self.ws.next().await {}
        Ok(())
    }

    /// Sends `frame` verbatim and reads the one response to it.
    async fn exchange(&mut self, frame: &str) -> Result<Response, ClientError> {
        self.ws
            .send(WsMessage::text(frame))
            .await
            .map_err(|e| ClientError::Transport(Box::new(e)))?;
        loop {
            let message = match self.ws.next().await {
                Some(Ok(m)) => m,
                Some(Err(e)) => return Err(ClientError::Transport(Box::new(e))),
                None => {
                    return Err(ClientError::Closed {
                        code: None,
                        reason: String::new(),
                    });
                }
            };
            match message {
                WsMessage::Text(text) => {
                    return serde_json::from_str(text.as_str()).map_err(|source| ClientError::BadResponse {
                        text: text.as_str().to_owned(),
                        source,
                    });
                }
                WsMessage::Close(frame) => {
                    return Err(ClientError::Closed {
                        code: frame.as_ref().map(|f| u16::from(f.code)),
                        reason: frame.map(|f| f.reason.as_str().to_owned()).unwrap_or_default(),
                    });
                }
                WsMessage::Binary(_) | WsMessage::Ping(_) | WsMessage::Pong(_) | WsMessage::Frame(_) => {}
            }
        }
    }
}

/// The `/events` URL of the server at `url` (DESIGN.md, "Events": the same
/// port and scheme as the command socket): `ws://host:53001` gives
/// `ws://host:53001/events`; a path is kept (`wss://proxy/drone-1/` gives
/// `wss://proxy/drone-1/events`), a query or fragment is dropped.
pub fn events_url(url: &str) -> String {
    let url = url.split(['?', '#']).next().unwrap_or_default();
    // After the scheme's `//`, the path starts at the first `/`, if any.
    let authority = url.find("//").map_or(0, |i| i + 2);
    let base = match url.get(authority..).and_then(|rest| rest.find('/')) {
        Some(_) => url.trim_end_matches('/'),
        None => url,
    };
    format!("{base}/events")
}

/// A subscription to a server's events: `/events`, logged in when the
/// server has a password (DESIGN.md, "Events").
///
/// Each event is a JSON object, `{"event":"<name>","seq":N,"boot":"<id>",
/// "ts":ms, ...}`; a subscriber that fell behind gets `{"event":"gap",
/// "missed":N,"ts":ms}` instead of the events it missed. The stream never
/// ends by itself: [`Events::next`] fails when the connection does.
///
/// ```no_run
/// # async fn demo() -> Result<(), lluav_host::client::ClientError> {
/// use lluav_host::client::{ConnectOptions, Events};
/// let mut events = Events::subscribe("ws://127.0.0.1:53001", &ConnectOptions::default(), Some("s3cret")).await?;
/// loop {
///     let event = events.next().await?;
///     println!("{} {}", event["event"], serde_json::Value::Object(event.clone()));
/// }
/// # }
/// ```
pub struct Events {
    ws: WebSocketStream<Transport>,
}

impl Events {
    /// How long the stream may be silent before it counts as lost: the
    /// server pings every subscriber every 10 s, so a connection that
    /// brings nothing for this long is gone (a cable pulled, a NAT that
    /// forgot it) even when TCP has not noticed.
    pub const SILENCE: std::time::Duration = std::time::Duration::from_secs(30);

    /// Connects to the `/events` of the server at `url` (the command
    /// socket's URL, see [`events_url`]) and, with a `password`, logs in: a
    /// refused login is [`ClientError::Failed`] with the server's answer
    /// (a wrong password counts as one, as on the command socket).
    pub async fn subscribe(
        url: &str,
        options: &ConnectOptions,
        password: Option<&str>,
    ) -> Result<Events, ClientError> {
        let mut client = Client::connect_with(&events_url(url), options).await?;
        if let Some(password) = password {
            // The login is answered before any event: the server
            // subscribes the session only once it is logged in.
            client.login(password).await?.check()?;
        }
        Ok(Events { ws: client.ws })
    }

    /// The next event (or gap) as its JSON object. Fails when the server
    /// closes the stream ([`ClientError::Closed`]: 1001 when lluavd stops,
    /// 1008 when a login was due and none came), when the connection
    /// breaks or stays silent for [`Events::SILENCE`]
    /// ([`ClientError::Transport`]), or when a message is not a JSON object
    /// ([`ClientError::BadEvent`]).
    pub async fn next(&mut self) -> Result<Map<String, Value>, ClientError> {
        use tokio_tungstenite::tungstenite::Error as WsError;
        loop {
            let message = match tokio::time::timeout(Events::SILENCE, self.ws.next()).await {
                Err(_) => {
                    let why = format!(
                        "no word from the server for {} s (it pings every 10 s)",
                        Events::SILENCE.as_secs()
                    );
                    let timed_out = std::io::Error::new(std::io::ErrorKind::TimedOut, why);
                    return Err(ClientError::Transport(Box::new(WsError::Io(timed_out))));
                }
                Ok(Some(Ok(m))) => m,
                Ok(Some(Err(e))) => return Err(ClientError::Transport(Box::new(e))),
                Ok(None) => {
                    return Err(ClientError::Closed {
                        code: None,
                        reason: String::new(),
                    });
                }
            };
            match message {
                WsMessage::Text(text) => {
                    return serde_json::from_str(text.as_str()).map_err(|e| ClientError::BadEvent {
                        text: text.as_str().chars().take(200).collect(),
                        why: e.to_string(),
                    });
                }
                WsMessage::Binary(bytes) => {
                    return Err(ClientError::BadEvent {
                        text: format!("<{} bytes>", bytes.len()),
                        why: "a binary message".into(),
                    });
                }
                WsMessage::Close(frame) => {
                    return Err(ClientError::Closed {
                        code: frame.as_ref().map(|f| u16::from(f.code)),
                        reason: frame.map(|f| f.reason.as_str().to_owned()).unwrap_or_default(),
                    });
                }
                // Pings are answered by tungstenite while it reads.
                WsMessage::Ping(_) | WsMessage::Pong(_) | WsMessage::Frame(_) => {}
            }
        }
    }

    /// Closes the stream cleanly (the WebSocket closing handshake).
    pub async fn close(mut self) -> Result<(), ClientError> {
        self.ws
            .close(None)
            .await
            .map_err(|e| ClientError::Transport(Box::new(e)))?;
        while let Some(Ok(_)) = self.ws.next().await {}
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::events_url;

    #[test]
    fn the_events_url_is_the_servers_with_events_for_its_path() {
        for (server, events) in [
            ("ws://127.0.0.1:53001", "ws://127.0.0.1:53001/events"),
            ("ws://127.0.0.1:53001/", "ws://127.0.0.1:53001/events"),
            ("wss://[::1]:53001", "wss://[::1]:53001/events"),
            (
                "wss://proxy.example/drone-1/",
                "wss://proxy.example/drone-1/events",
            ),
            ("ws://h:1/?x=1#y", "ws://h:1/events"),
        ] {
            assert_eq!(events_url(server), events, "{server}");
        }
    }
}
