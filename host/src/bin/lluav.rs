//! `lluav`: the LLUAV command-line client.
//!
//! `lluav [--url URL] [--cafile FILE] [--password P] COMMAND [ARGS]` sends one command and
//! prints its response as pretty JSON; the exit status is 0 when `ret` is
//! 0, 1 when the command failed or the server could not be reached, 2 when
//! the command line is not a valid request. Without a command it starts an
//! interactive session with history and completion of command names.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use lluav_core::{Grammar, TABLE};
use lluav_host::client::{Client, ClientError, ConnectOptions, DEFAULT_URL, Response};
use rustyline::completion::{Completer, Pair};
use rustyline::error::ReadlineError;
use rustyline::highlight::Highlighter;
use rustyline::hint::Hinter;
use rustyline::history::DefaultHistory;
use rustyline::validate::Validator;
use rustyline::{CompletionType, Config, Context, Editor, Helper};
use tokio::runtime::Runtime;

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
    if cli.command.is_empty() {
        repl(&runtime, &cli)
    } else {
        one_shot(&runtime, &cli, &cli.command.join(" "))
    }
}

fn one_shot(runtime: &Runtime, cli: &Cli, line: &str) -> ExitCode {
    // Catch a malformed request here, with its usage line, before dialling.
    if let Err(e) = lluav_core::parse(line) {
        eprintln!("lluav: {e}");
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
                    eprintln!("lluav: {line}: {msg} (ret {})", response.ret);
                }
                ExitCode::FAILURE
            } else {
                ExitCode::SUCCESS
            }
        }
        Err(e) => {
            eprintln!("lluav: {e}");
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

fn print_response(response: &Response) {
    match serde_json::to_string_pretty(&response.to_json()) {
        Ok(text) => println!("{text}"),
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

/// Sends one line of the interactive session and prints the answer;
/// drops the connection after a transport error (the next line reconnects).
fn send_line(runtime: &Runtime, cli: &Cli, client: &mut Option<Client>, line: &str) {
    let reply = runtime.block_on(async {
        let c = match client {
            Some(c) => c,
            None => client.insert(connect(cli).await?),
        };
        c.send_line(line).await
    });
    match reply {
        Ok(response) => print_response(&response),
        Err(e @ ClientError::Parse(_)) => eprintln!("{e}"),
        Err(e) => {
            eprintln!("lluav: {e}; the next command reconnects");
            *client = None;
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
    let mut client = match runtime.block_on(connect(cli)) {
        Ok(c) => Some(c),
        Err(e) => {
            eprintln!("lluav: {e}");
            return ExitCode::FAILURE;
        }
    };
    println!(
        "connected to {}. `help` lists the commands, `help NAME` shows one; Tab completes; Ctrl-D quits.",
        cli.url
    );
    loop {
        let line = match editor.readline("lluav> ") {
            Ok(line) => line,
            Err(ReadlineError::Interrupted) => continue,
            Err(ReadlineError::Eof) => break,
            Err(e) => {
                eprintln!("lluav: {e}");
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
            _ => send_line(runtime, cli, &mut client, line),
        }
    }
    if let Some(path) = &history
        && let Err(e) = editor.save_history(path)
    {
        eprintln!("lluav: history not saved to {}: {e}", path.display());
    }
    if let Some(c) = client {
        let _ = runtime.block_on(c.close());
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
            if !spec.flags.run_on_arm {
                notes.push("refused while armed");
            }
            if !spec.flags.run_in_lock {
                notes.push("refused in lock mode unless admin");
            }
            if spec.flags.admin_only {
                notes.push("admin only");
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
            .filter(|s| s.name.starts_with(word))
            .map(|s| Pair {
                display: s.usage.to_owned(),
                replacement: format!("{} ", s.name),
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
