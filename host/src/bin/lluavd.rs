//! `lluavd`: the LLUAV WebSocket daemon serving a simulated vehicle.
//!
//! Prints exactly one line to stdout, `listening on ws://HOST:PORT`, once it
//! accepts connections; logs go to stderr (`RUST_LOG`, default `info`) and
//! into the buffer `showmsg` reads. SIGINT or SIGTERM: stop accepting,
//! answer what is in flight, flush, exit 0. Under systemd it speaks
//! sd_notify (`READY=1` after that line, the watchdog, `STATUS=`,
//! `STOPPING=1`) and logs with the journal's priority prefixes;
//! `--check-config` checks and prints the settings instead of serving.

use std::io::{IsTerminal as _, Write as _};
use std::process::ExitCode;

use clap::Parser;
use lluav_host::config::{Cli, Settings};
use lluav_host::daemon::{Daemon, DaemonError};
use lluav_host::journal::{self, JournalFormat};
use lluav_host::notify::Notifier;
use lluav_host::recent_log::RecentLog;
use lluav_host::vehicle::Vehicle;
use tokio::signal::unix::{Signal, SignalKind, signal};
use tracing::{error, info, warn};
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::{EnvFilter, fmt};

/// Log lines kept for `showmsg`/`savemsg`.
const RECENT_LOG_LINES: usize = 1000;

fn main() -> ExitCode {
    // Before any thread: the uplink's memory bound counts on it.
    lluav_host::malloc::limit_arenas();
    let cli = Cli::parse();
    if cli.check_config {
        return lluav_host::check_config::run(cli);
    }
    let settings = match Settings::from_cli(cli) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("lluavd: {e}");
            return ExitCode::from(2);
        }
    };
    let log = RecentLog::new(RECENT_LOG_LINES);
    // Under systemd, the journal stamps each line and reads its priority
    // from a `<N>` prefix.
    let journal = journal::stderr_is_journal();
    tracing_subscriber::registry()
        .with(EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info")))
        .with((!journal).then(|| {
            fmt::layer()
                .with_writer(std::io::stderr)
                .with_ansi(std::io::stderr().is_terminal())
        }))
        .with(journal.then(|| {
            fmt::layer()
                .with_writer(std::io::stderr)
                .event_format(JournalFormat::default())
        }))
        .with(log.layer())
        .init();
    let runtime = match tokio::runtime::Builder::new_multi_thread().enable_all().build() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("lluavd: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    runtime.block_on(run(settings, log))
}

async fn run(settings: Settings, log: RecentLog) -> ExitCode {
    // Signal handlers go in before the "listening" line, so that a
    // supervisor may signal as soon as it has read it.
    let notifier = Notifier::from_env();
    let (term, int) = match (signal(SignalKind::terminate()), signal(SignalKind::interrupt())) {
        (Ok(t), Ok(i)) => (t, i),
        (Err(e), _) | (_, Err(e)) => {
            eprintln!("lluavd: cannot install signal handlers: {e}");
            return ExitCode::FAILURE;
        }
    };
    let signals = (term, int);
    match settings.mavlink.clone() {
        Some(address) => {
            serve(
                Daemon::open_mavlink(&settings, log, &address).await,
                &settings,
                signals,
                notifier,
            )
            .await
        }
        None => serve(Daemon::open(&settings, log).await, &settings, signals, notifier).await,
    }
}

/// Serves an opened daemon until SIGINT or SIGTERM.
async fn serve<V: Vehicle>(
    opened: Result<Daemon<V>, DaemonError>,
    settings: &Settings,
    (mut term, mut int): (Signal, Signal),
    notifier: Option<Notifier>,
) -> ExitCode {
    let daemon = match opened {
        Ok(d) => d.notify(notifier.clone()),
        Err(e) => {
            eprintln!("lluavd: {e}");
            return ExitCode::from(2);
        }
    };
    let addr = match daemon.local_addr() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("lluavd: cannot read the bound address: {e}");
            return ExitCode::FAILURE;
        }
    };
    warn_about_public_admin_value(settings);
    info!(%addr, data_dir = %settings.data_dir.display(), mavlink = settings.mavlink.as_deref().unwrap_or("-"), "lluavd ready");
    let mut stdout = std::io::stdout().lock();
    if writeln!(stdout, "listening on {}://{addr}", daemon.scheme())
        .and_then(|()| stdout.flush())
        .is_err()
    {
        // Whoever started us is gone; serving anyway would be invisible.
        return ExitCode::FAILURE;
    }
    drop(stdout);
    if let Some(n) = &notifier {
        n.ready(&format!("listening on {}://{addr}", daemon.scheme()));
    }
    let shutdown = async move {
        tokio::select! {
            _ = term.recv() => info!("SIGTERM: shutting down"),
            _ = int.recv() => info!("SIGINT: shutting down"),
        }
        if let Some(n) = &notifier {
            n.stopping();
        }
    };
    match daemon.run(shutdown).await {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            error!("{e}");
            ExitCode::FAILURE
        }
    }
}

/// The admin login value `1025` is in the public spec: beyond loopback or
/// through the broker, anyone who can reach the vehicle could use it
/// (lluavd starts so only with `--allow-default-admin`).
fn warn_about_public_admin_value(settings: &Settings) {
    let public = settings.admin_password == lluav_core::session::DEFAULT_ADMIN_PASSWORD;
    let reachable = !settings.bind.ip().is_loopback() || settings.uplink.is_some();
    if public && !settings.echo && reachable {
        warn!(
            bind = %settings.bind,
            "the admin login value is the protocol's public default (1025) and this daemon is reachable \
             beyond loopback or through the broker: anyone who can connect can log in as admin. Set `admin_password = \"...\"` \
             in the config file (--config FILE) to change it"
        );
    }
}
