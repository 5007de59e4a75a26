//! A typed async client for any LLUAV server (lluavd, a board, the real
//! firmware).
//!
//! Requests are [`Command`]s, encoded by lluav-core's encoder, so a request
//! this client sends is valid by construction and every command of the
//! table is reachable through [`Client::send`] or [`Client::call`]; a few
//! common commands have typed helpers. Replies are [`Response`]s: `ret`,
//! `cmd`, `ts` and the command-specific fields.
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

use futures_util::{SinkExt, StreamExt};
use lluav_core::{ArgError, Args, Command, CommandId, ParseError, Pose};
use serde::Deserialize;
use serde_json::{Map, Value};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message as WsMessage;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

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

/// A connection to one server; requests are answered in order.
pub struct Client {
    ws: WebSocketStream<MaybeTlsStream<TcpStream>>,
    frame: String,
}

impl Client {
    /// Connects to `url` (`ws://host:port`).
    pub async fn connect(url: &str) -> Result<Client, ClientError> {
        let (ws, _) = tokio_tungstenite::connect_async(url)
            .await
            .map_err(|e| ClientError::Connect {
                url: url.to_owned(),
                source: Box::new(e),
            })?;
        Ok(Client {
            ws,
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
