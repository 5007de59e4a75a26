//! `lluav`: the LLUAV command-line client.
//!
//! `lluav [--url URL] [--cafile FILE] [--password P] COMMAND [ARGS]` sends one command and
//! prints its response as pretty JSON; the exit status is 0 when `ret` is
//! 0, 1 when the command failed or the server could not be reached, 2 when
//! the command line is not a valid request. Without a command it starts an
//! interactive session with history and completion of command names.
//!
//! `lluav events [--json] [--reconnect]` follows the server's `/events`
//! stream: one line per event until Ctrl-C (exit 0); a refused login or a
//! connection that ends exits 1 (unless `--reconnect`).
//!
//! Through an MQTT broker (lluavd's uplink): `lluav --broker URL fleet
//! [--json]` lists the vehicles; `lluav --broker URL --vehicle V[,V2...]
//! COMMAND` runs a command on each (one line per vehicle when several);
//! `lluav --broker URL --vehicle V` is the interactive session with V;
//! `lluav --broker URL events [--vehicle V[,V2...]] [--json]` follows the
//! vehicles' events (`lluav/V/events`), each line prefixed with `V: `.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::Parser;
use lluav_core::{Grammar, TABLE};
use lluav_host::client::{Client, ClientError, ConnectOptions, DEFAULT_URL, Response};
use lluav_host::terminal::{escape, escape_lines};
use lluav_host::uplink::fleet::{self, Fleet, FleetError, FleetOptions};
use rustyline::completion::{Completer, Pair};
use rustyline::error::ReadlineError;
use rustyline::highlight::Highlighter;
use rustyline::hint::Hinter;
use rustyline::history::DefaultHistory;
use rustyline::validate::Validator;
use rustyline::{CompletionType, Config, Context, Editor, Helper};
use tokio::runtime::Runtime;

#[path = "lluav/events.rs"]
mod events;

/// The LLUAV command-line client: one command, or an interactive session.
#[derive(Debug, Parser)]
#[command(name = "lluav", version)]
struct Cli {
    /// The server: ws://HOST:PORT, or wss://HOST:PORT for TLS.
    #[arg(long, default_value = DEFAULT_URL, value_name = "URL")]
    url: String,
    /// For wss:// servers with a self-signed certificate: a PEM file of the
    /// certificates to trust (e.g. the server's own) instead of the system's.
    #[arg(long, env = "LLUAV_CAFILE", value_name = "FILE")]
    cafile: Option<PathBuf>,
    /// Log in with this password first.
    #[arg(long, env = "LLUAV_PASSWORD", hide_env_values = true, value_name = "P")]
    password: Option<String>,
    /// Reach vehicles through this MQTT broker (lluavd --uplink) instead:
    /// mqtt://HOST or mqtt://HOST:PORT (1883), mqtts://... for TLS (8883).
    #[arg(long, value_name = "URL", conflicts_with = "url")]
    broker: Option<String>,
    /// With --broker: the vehicle(s) to command, comma-separated.
    #[arg(long, value_name = "V[,V2...]", value_delimiter = ',', requires = "broker")]
    vehicle: Vec<String>,
    /// With --broker: the user name at the broker.
    #[arg(long, value_name = "USER", requires = "broker")]
    broker_user: Option<String>,
    /// With --broker: the password at the broker.
    #[arg(long, env = "LLUAV_BROKER_PASSWORD", hide_env_values = true, value_name = "P")]
    broker_password: Option<String>,
    /// With an mqtts:// broker: a PEM file of the certificates to trust
    /// instead of the system's.
    #[arg(long, env = "LLUAV_BROKER_CAFILE", value_name = "FILE")]
    broker_cafile: Option<PathBuf>,
    /// With --broker: this operator's client id (1-64 of [A-Za-z0-9_-]);
    /// each client id is one session on each vehicle. [default: the broker
    /// user name, else lluav-RANDOM]
    #[arg(long, value_name = "ID", requires = "broker")]
    client_id: Option<String>,
    /// With --broker: seconds to wait for each vehicle's answer.
    #[arg(long, value_name = "SECS", default_value_t = 5.0, requires = "broker")]
    timeout: f64,
    /// Print JSON: with `--broker URL fleet`, the fleet; with `events`,
    /// each event as the server sent it (one object a line).
    #[arg(long)]
    json: bool,
    /// With `events`: keep following when the connection ends (lluavd
    /// restarts, the network drops), reconnecting with a growing pause
    /// and saying on stderr what may have been missed; a refused login
    /// still ends it.
    #[arg(long)]
    reconnect: bool,
    /// The command and its arguments, e.g. `state` or `set_sp_ned 1:2:-3:0`;
    /// none starts the interactive session.
    #[arg(trailing_var_arg = true, allow_hyphen_values = true, value_name = "COMMAND")]
    command: Vec<String>,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let runtime = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("lluav: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    if cli.broker.is_some() {
        return through_broker(&runtime, cli);
    }
    if cli.command.first().is_some_and(|c| c == "events") {
        return events::follow(&runtime, cli);
    }
    // These used to need --broker (clap said so); they still mean nothing
    // for one command.
    if cli.json || cli.reconnect {
        eprintln!(
            "lluav: --json and --reconnect are for `lluav events` (and --json for `lluav --broker URL fleet`)"
        );
        return ExitCode::from(2);
    }
    if cli.command.is_empty() {
        repl(&runtime, &cli)
    } else {
        one_shot(&runtime, &cli, &cli.command.join(" "))
    }
}

/// `--broker`: the fleet listing, a command on each vehicle, or the
/// interactive session with one.
fn through_broker(runtime: &Runtime, mut cli: Cli) -> ExitCode {
    if cli.command.first().is_some_and(|c| c == "events") {
        return events::follow_broker(runtime, cli);
    }
    // `fleet --json` as well as `--json fleet`.
    if cli.command.first().is_some_and(|c| c == "fleet") && cli.command.iter().skip(1).all(|a| a == "--json")
    {
        cli.json |= cli.command.len() > 1;
        return runtime.block_on(list_fleet(&cli));
    }
    let line = cli.command.join(" ");
    let lines = !line.is_empty();
    match (cli.vehicle.as_slice(), lines) {
        ([], _) => {
            eprintln!(
                "lluav: with --broker, name the vehicle(s) with --vehicle V[,V2...], or list them: lluav --broker URL fleet"
            );
            ExitCode::from(2)
        }
        ([_, _, ..], false) => {
            eprintln!("lluav: the interactive session talks to one vehicle: --vehicle V");
            ExitCode::from(2)
        }
        (_, true) => match lluav_core::parse(&line) {
            Ok(_) => runtime.block_on(on_vehicles(&cli, &line)),
            Err(e) => {
                eprintln!("lluav: {}", escape(&e.to_string()));
                ExitCode::from(2)
            }
        },
        ([_], false) => repl(runtime, &cli),
    }
}

/// Connects to the broker of `--broker`.
async fn fleet(cli: &Cli) -> Result<Fleet, FleetError> {
    let options = FleetOptions {
        client_id: cli.client_id.clone(),
        user: cli.broker_user.clone(),
        password: cli.broker_password.clone(),
        cafile: cli.broker_cafile.clone(),
    };
    Fleet::connect(cli.broker.as_deref().unwrap_or_default(), &options).await
}

fn wait(cli: &Cli) -> Duration {
    Duration::try_from_secs_f64(cli.timeout).unwrap_or(Duration::from_secs(5))
}

/// `lluav --broker URL fleet [--json]`.
async fn list_fleet(cli: &Cli) -> ExitCode {
    let fleet = match fleet(cli).await {
        Ok(f) => f,
        Err(e) => {
            eprintln!("lluav: {}", escape(&e.to_string()));
            return ExitCode::FAILURE;
        }
    };
    let vehicles = fleet.vehicles().await;
    if cli.json {
        let object: serde_json::Map<String, serde_json::Value> =
            vehicles.iter().map(|v| (v.id.clone(), v.to_json())).collect();
        println!("{}", escape(&serde_json::Value::Object(object).to_string()));
    } else {
        print!("{}", fleet::table(&vehicles));
    }
    fleet.close().await;
    ExitCode::SUCCESS
}

/// Logs in to `vehicle` when a password is given, then sends `line`.
async fn on_vehicle(fleet: &Fleet, cli: &Cli, vehicle: &str, line: &str) -> Result<Response, FleetError> {
    if let Some(password) = &cli.password {
        let login = frame(&format!("login {password}")).unwrap_or_default();
        let response = fleet.request(vehicle, &login, wait(cli)).await?;
        if response.ret < 0 {
            return Ok(response);
        }
    }
    fleet
        .request(vehicle, &frame(line).unwrap_or_default(), wait(cli))
        .await
}

/// `lluav --broker URL --vehicle V[,V2...] COMMAND`: all at once, one
/// line per vehicle (pretty JSON for one).
async fn on_vehicles(cli: &Cli, line: &str) -> ExitCode {
    let fleet = match fleet(cli).await {
        Ok(f) => f,
        Err(e) => {
            eprintln!("lluav: {}", escape(&e.to_string()));
            return ExitCode::FAILURE;
        }
    };
    let answers =
        futures_util::future::join_all(cli.vehicle.iter().map(|v| on_vehicle(&fleet, cli, v, line))).await;
    let mut failed = false;
    for (vehicle, answer) in cli.vehicle.iter().zip(answers) {
        match answer {
            Ok(response) if cli.vehicle.len() == 1 => {
                print_response(&response);
                failed |= response.ret < 0;
            }
            Ok(response) => {
                println!("{vehicle}: {}", escape(&response.to_json().to_string()));
                failed |= response.ret < 0;
            }
            Err(e) => {
                eprintln!("{vehicle}: lluav: {}", escape(&e.to_string()));
                failed = true;
            }
        }
    }
    fleet.close().await;
    if failed {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}

fn one_shot(runtime: &Runtime, cli: &Cli, line: &str) -> ExitCode {
    // Catch a malformed request here, with its usage line, before dialling.
    if let Err(e) = lluav_core::parse(line) {
        eprintln!("lluav: {}", escape(&e.to_string()));
        return ExitCode::from(2);
    }
    let answered = runtime.block_on(async {
        let mut client = connect(cli).await?;
        let response = client.send_line(line).await?;
        // The answer is in; a failed close does not change it.
        let _ = client.close().await;
        Ok::<_, ClientError>(response)
    });
    match answered {
        Ok(response) => {
            print_response(&response);
            if response.ret < 0 {
                if let Some(msg) = response.msg() {
                    eprintln!("lluav: {line}: {} (ret {})", escape(msg), response.ret);
                }
                ExitCode::FAILURE
            } else {
                ExitCode::SUCCESS
            }
        }
        Err(e) => {
            eprintln!("lluav: {}", escape(&e.to_string()));
            ExitCode::FAILURE
        }
    }
}

/// Connects and, when a password is given, logs in (a refused login is an
/// error: every command after it would be refused too).
async fn connect(cli: &Cli) -> Result<Client, ClientError> {
    let options = ConnectOptions {
        ca_file: cli.cafile.clone(),
    };
    let mut client = Client::connect_with(&cli.url, &options)
        .await
        .map_err(with_hint)?;
    if let Some(password) = &cli.password {
        client.login(password).await?.check()?;
    }
    Ok(client)
}

/// Adds what to check to a connection failure: whether lluavd runs, or
/// which certificate to trust.
fn with_hint(e: ClientError) -> ClientError {
    use tokio_tungstenite::tungstenite::Error as WsError;
    let ClientError::Connect { url, source } = e else {
        return e;
    };
    let hint = match &*source {
        WsError::Io(io) if io.kind() == std::io::ErrorKind::ConnectionRefused => " (is lluavd running?)",
        WsError::Io(io) if io.to_string().contains("certificate") => {
            " (a self-signed server certificate needs --cafile FILE)"
        }
        _ => "",
    };
    ClientError::Connect {
        url: format!("{url}{hint}"),
        source,
    }
}

/// Prints a response as pretty JSON, escaped for the terminal (a vehicle
/// could send control characters serde_json writes as they are: DEL, C1,
/// format characters).
fn print_response(response: &Response) {
    match serde_json::to_string_pretty(&response.to_json()) {
        Ok(text) => println!("{}", escape_lines(&text)),
        Err(e) => eprintln!("lluav: cannot print the response: {e}"),
    }
}

/// The line editor with completion, and the history loaded from `history`.
fn editor(history: Option<&PathBuf>) -> rustyline::Result<Editor<Commands, DefaultHistory>> {
    // Bash-like: Tab completes the common prefix, a second Tab lists the
    // candidates with their usage lines.
    let config = Config::builder().completion_type(CompletionType::List).build();
    let mut editor = Editor::with_config(config)?;
    editor.set_helper(Some(Commands));
    if let Some(path) = history {
        if let Some(dir) = path.parent() {
            let _ = std::fs::create_dir_all(dir);
        }
        // No history yet is the normal first run.
        let _ = editor.load_history(path);
    }
    Ok(editor)
}

/// What the interactive session talks to: a server over WebSocket, or a
/// vehicle through a broker.
enum Link {
    Ws(Box<Client>),
    Broker(Fleet, String),
}

/// Why a line got no answer.
enum Failed {
    /// The line is not a request: nothing was sent.
    Parse(String),
    /// The link is broken: the next line reconnects.
    Link(String),
    /// The vehicle did not answer; the link is fine.
    Vehicle(String),
}

impl Link {
    /// Connects as the command line says (and logs in with `--password`).
    async fn open(cli: &Cli) -> Result<Link, String> {
        match (&cli.broker, cli.vehicle.first()) {
            (Some(_), Some(vehicle)) => {
                let fleet = fleet(cli).await.map_err(|e| e.to_string())?;
                if let Some(password) = &cli.password {
                    let login = frame(&format!("login {password}")).map_err(|e| e.to_string())?;
                    let response = fleet.request(vehicle, &login, wait(cli)).await;
                    response
                        .map_err(|e| e.to_string())?
                        .check()
                        .map_err(|e| e.to_string())?;
                }
                Ok(Link::Broker(fleet, vehicle.clone()))
            }
            _ => connect(cli)
                .await
                .map(|c| Link::Ws(Box::new(c)))
                .map_err(|e| e.to_string()),
        }
    }

    async fn send(&mut self, cli: &Cli, line: &str) -> Result<Response, Failed> {
        match self {
            Link::Ws(client) => client.send_line(line).await.map_err(|e| match e {
                ClientError::Parse(_) => Failed::Parse(e.to_string()),
                e => Failed::Link(e.to_string()),
            }),
            Link::Broker(fleet, vehicle) => {
                let frame = frame(line).map_err(Failed::Parse)?;
                fleet
                    .request(vehicle, &frame, wait(cli))
                    .await
                    .map_err(|e| match e {
                        FleetError::Lost(_) => Failed::Link(e.to_string()),
                        e => Failed::Vehicle(e.to_string()),
                    })
            }
        }
    }

    async fn close(self) {
        match self {
            Link::Ws(client) => {
                let _ = client.close().await;
            }
            Link::Broker(fleet, _) => fleet.close().await,
        }
    }
}

/// The canonical frame of `line`, or why it is not a request.
fn frame(line: &str) -> Result<String, String> {
    let command = lluav_core::parse(line).map_err(|e| e.to_string())?;
    let mut frame = String::new();
    // Writing into a String cannot fail.
    let _ = command.encode(&mut frame);
    Ok(frame)
}

/// Sends one line of the interactive session and prints the answer;
/// drops the connection after a transport error (the next line reconnects).
fn send_line(runtime: &Runtime, cli: &Cli, link: &mut Option<Link>, line: &str) {
    let reply = runtime.block_on(async {
        let l = match link {
            Some(l) => l,
            None => link.insert(Link::open(cli).await.map_err(Failed::Link)?),
        };
        l.send(cli, line).await
    });
    match reply {
        Ok(response) => print_response(&response),
        Err(Failed::Parse(e)) => eprintln!("{e}"),
        Err(Failed::Vehicle(e)) => eprintln!("lluav: {}", escape(&e)),
        Err(Failed::Link(e)) => {
            eprintln!("lluav: {}; the next command reconnects", escape(&e));
            *link = None;
        }
    }
}

fn repl(runtime: &Runtime, cli: &Cli) -> ExitCode {
    let history = history_file();
    let mut editor = match editor(history.as_ref()) {
        Ok(e) => e,
        Err(e) => {
            eprintln!("lluav: cannot start the line editor: {e}");
            return ExitCode::FAILURE;
        }
    };
    let mut link = match runtime.block_on(Link::open(cli)) {
        Ok(l) => Some(l),
        Err(e) => {
            eprintln!("lluav: {}", escape(&e.to_string()));
            return ExitCode::FAILURE;
        }
    };
    let peer = match (&cli.broker, cli.vehicle.first()) {
        (Some(broker), Some(vehicle)) => format!("vehicle {vehicle} through {broker}"),
        _ => cli.url.clone(),
    };
    println!(
        "connected to {peer}. `help` lists the commands, `help NAME` shows one; Tab completes; Ctrl-D quits."
    );
    loop {
        let line = match editor.readline("lluav> ") {
            Ok(line) => line,
            Err(ReadlineError::Interrupted) => continue,
            Err(ReadlineError::Eof) => break,
            Err(e) => {
                eprintln!("lluav: {}", escape(&e.to_string()));
                break;
            }
        };
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        // Duplicates and other refusals of the history are not worth a word;
        // saving at once keeps the history of a session that gets killed.
        let _ = editor.add_history_entry(line);
        if let Some(path) = &history {
            let _ = editor.save_history(path);
        }
        match line.split_once(' ').map_or((line, ""), |(a, b)| (a, b.trim())) {
            ("quit" | "exit", _) => break,
            ("help", "") => print_table(),
            ("help", name) => print_command(name),
            _ => send_line(runtime, cli, &mut link, line),
        }
    }
    if let Some(path) = &history
        && let Err(e) = editor.save_history(path)
    {
        eprintln!("lluav: history not saved to {}: {e}", path.display());
    }
    if let Some(l) = link {
        runtime.block_on(l.close());
    }
    ExitCode::SUCCESS
}

fn history_file() -> Option<PathBuf> {
    let dirs = directories::ProjectDirs::from("", "", "lluav")?;
    let dir = dirs.state_dir().unwrap_or_else(|| dirs.data_local_dir());
    Some(dir.join("repl-history"))
}

fn print_table() {
    let width = TABLE.iter().map(|s| s.usage.len()).max().unwrap_or(0);
    for spec in &TABLE {
        println!("  {:width$}  {}", spec.usage, spec.summary());
    }
}

fn print_command(name: &str) {
    match lluav_core::table::lookup(name) {
        Some(spec) => {
            println!("{}\n  {}", spec.usage, spec.summary());
            let mut notes = Vec::new();
            if !spec.flags.run_on_arm() {
                notes.push("refused while armed");
            }
            if !spec.flags.run_in_lock() {
                notes.push("refused in lock mode unless admin");
            }
            if spec.flags.admin_only() {
                notes.push("admin only");
            }
            match spec.class {
                lluav_core::table::Class::Motion => {
                    notes.push("only from the session in control, never in a failsafe")
                }
                lluav_core::table::Class::StopsMission => {
                    notes.push("while a mission runs: only from the session in control, never in a failsafe")
                }
                lluav_core::table::Class::Conservative => notes.push("open to every session; takes control"),
                lluav_core::table::Class::Return => {
                    notes.push("open to every session; takes control; refused while a failsafe lands")
                }
                lluav_core::table::Class::Neutral => {}
            }
            if !notes.is_empty() {
                println!("  ({})", notes.join("; "));
            }
        }
        None => eprintln!("no command `{name}`; `help` lists them"),
    }
}

/// Completion of command names and hints of their arguments, from core's
/// table.
struct Commands;

impl Completer for Commands {
    type Candidate = Pair;

    fn complete(&self, line: &str, pos: usize, _: &Context<'_>) -> rustyline::Result<(usize, Vec<Pair>)> {
        let typed = line.get(..pos).unwrap_or(line);
        // Only the first word is a command name (or `help NAME`).
        let (start, word) = match typed.split_once(' ') {
            None => (0, typed),
            Some(("help", rest)) if !rest.contains(' ') => (typed.len() - rest.len(), rest),
            Some(_) => return Ok((pos, Vec::new())),
        };
        let matches = TABLE
            .iter()
            .filter(|s| s.name().starts_with(word))
            .map(|s| Pair {
                display: s.usage.to_owned(),
                replacement: format!("{} ", s.name()),
            })
            .collect();
        Ok((start, matches))
    }
}

impl Hinter for Commands {
    type Hint = String;

    fn hint(&self, line: &str, pos: usize, _: &Context<'_>) -> Option<String> {
        if pos != line.len() {
            return None;
        }
        let name = line.strip_suffix(' ')?;
        let spec = lluav_core::table::lookup(name)?;
        if spec.grammar == Grammar::None {
            return None;
        }
        spec.usage.split_once(' ').map(|(_, args)| args.to_owned())
    }
}

impl Highlighter for Commands {}
impl Validator for Commands {}
impl Helper for Commands {}
