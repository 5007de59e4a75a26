//! `lluavd`'s settings: command line, environment and an optional TOML file.
//!
//! Precedence: a command-line flag (or its environment variable) wins over
//! the config file, which wins over the defaults. The password has one more
//! source, the simulator's stored password, which [`crate::daemon`] consults
//! when none of these gives one.

use std::net::{Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::time::Duration;

use clap::Parser;
use serde::{Deserialize, Serialize};

use crate::mavlink::{Limits as FlightLimits, SigningKey, Wanted};
use crate::net::{Limits, Policy};

/// The default address: loopback only, the protocol's port.
pub const DEFAULT_BIND: SocketAddr = SocketAddr::new(std::net::IpAddr::V4(Ipv4Addr::LOCALHOST), 53001);

/// `lluavd`'s command line.
#[derive(Debug, Default, Parser)]
#[command(
    name = "lluavd",
    version,
    about = "The LLUAV WebSocket daemon, serving a simulated vehicle"
)]
pub struct Cli {
    /// Address to listen on; port 0 picks a free port. [default: 127.0.0.1:53001]
    #[arg(long, value_name = "ADDR")]
    pub bind: Option<SocketAddr>,
    /// Login password (1-32 printable ASCII characters, no space).
    #[arg(long, env = "LLUAV_PASSWORD", hide_env_values = true, value_name = "PASS")]
    pub password: Option<String>,
    /// Where parameters, maps, images and bags live. [default: a per-user data directory]
    #[arg(long, value_name = "DIR")]
    pub data_dir: Option<PathBuf>,
    /// A TOML file with any of these settings (the flags win).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Simulation time factor: 2 runs the vehicle twice as fast. [default: 1]
    #[arg(long, value_name = "X")]
    pub sim_speed: Option<f64>,
    /// Fly a real autopilot over MAVLink instead of the simulator. ADDRESS
    /// in the mavlink crate's syntax: udpin:0.0.0.0:14540, udpout:HOST:PORT,
    /// tcpout:HOST:PORT, serial:/dev/ttyACM0:57600.
    #[arg(long, value_name = "ADDRESS")]
    pub mavlink: Option<String>,
    /// The autopilot --mavlink follows: its MAVLink system id, or `any`
    /// for the first autopilot that heartbeats. [default: 1]
    #[arg(long, value_name = "N|any")]
    pub mavlink_system: Option<Wanted>,
    /// Sign MAVLink 2 with the key in FILE (32 bytes as 64 hex digits) and
    /// drop every message from the autopilot not signed with it.
    #[arg(long, value_name = "FILE")]
    pub mavlink_signing_key: Option<PathBuf>,
    /// The MAVLink vehicle's lowest target altitude above home, in metres
    /// (0.2-10; the simulator's limits are its parameters). [default: 0.5]
    #[arg(long, value_name = "M")]
    pub min_alt: Option<f64>,
    /// The MAVLink vehicle's highest target altitude above home, in metres
    /// (1-500). [default: 120]
    #[arg(long, value_name = "M")]
    pub max_alt: Option<f64>,
    /// The MAVLink vehicle's largest horizontal distance of a target from
    /// home, in metres (1-10000). [default: 500]
    #[arg(long, value_name = "M")]
    pub geofence_radius: Option<f64>,
    /// The MAVLink vehicle's takeoff altitude above home, in metres
    /// (0.5-120; clipped into min_alt..max_alt). [default: 2.5]
    #[arg(long, value_name = "M")]
    pub takeoff_alt: Option<f64>,
    /// Seconds without a request after which the session in control of
    /// the MAVLink vehicle loses it (1-3600). [default: 30]
    #[arg(long, value_name = "SECS")]
    pub control_timeout: Option<u32>,
    /// Allow listening beyond loopback without a password.
    #[arg(long)]
    pub allow_no_password: bool,
    /// Allow listening beyond loopback with the public admin login value
    /// 1025 (instead of `admin_password` in the config file).
    #[arg(long)]
    pub allow_default_admin: bool,
    /// Largest message accepted, in bytes; larger closes with 1009. [default: 65536]
    #[arg(long, value_name = "BYTES")]
    pub max_message: Option<usize>,
    /// Most connections served at once. [default: 256]
    #[arg(long, value_name = "N")]
    pub max_connections: Option<usize>,
    /// Most sessions from one client address (loopback included). [default: 8]
    #[arg(long, value_name = "N")]
    pub max_sessions_per_ip: Option<usize>,
    /// Most HTTP upgrades in progress at once; beyond it the oldest is dropped. [default: 128]
    #[arg(long, value_name = "N")]
    pub max_handshakes: Option<usize>,
    /// Most HTTP upgrades in progress from one client address. [default: 8]
    #[arg(long, value_name = "N")]
    pub max_handshakes_per_ip: Option<usize>,
    /// Seconds from accept to a complete upgrade request (TLS included). [default: 5]
    #[arg(long, value_name = "SECS")]
    pub handshake_timeout: Option<u64>,
    /// With a password, seconds a session may stay without logging in. [default: 10]
    #[arg(long, value_name = "SECS")]
    pub login_timeout: Option<u64>,
    /// Seconds of silence after which a connection is closed. [default: 300]
    #[arg(long, value_name = "SECS")]
    pub idle_timeout: Option<u64>,
    /// Seconds an address is locked out after 5 wrong passwords in a row;
    /// doubles with each further lockout, up to 15 minutes. [default: 30]
    #[arg(long, value_name = "SECS")]
    pub login_lockout: Option<u64>,
    /// Wrong passwords checked per second from all addresses together
    /// (1-1000); beyond it no password is checked. [default: 10]
    #[arg(long, value_name = "N")]
    pub login_rate: Option<u16>,
    /// Addresses the login lockout remembers; when all still matter, a
    /// password from a new address is not checked. [default: 4096]
    #[arg(long, value_name = "N")]
    pub login_addresses: Option<usize>,
    /// A web origin allowed to open sessions besides pages served by this
    /// server (e.g. `https://gcs.example:8443`); `*` allows any. Repeatable.
    #[arg(long, value_name = "URL")]
    pub allow_origin: Vec<String>,
    /// A host name clients may reach this server by, besides its address
    /// (and localhost on loopback), e.g. drone.local. Repeatable.
    #[arg(long, value_name = "NAME")]
    pub allow_host: Vec<String>,
    /// Serve wss:// with this PEM certificate chain (needs --tls-key).
    #[arg(long, value_name = "FILE", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// The PEM private key of --tls-cert.
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Do not serve the browser console: plain HTTP requests get 404.
    #[arg(long)]
    pub no_console: bool,
    /// Serve a WebSocket echo instead of the protocol, through the same
    /// connection code: for the Autobahn|Testsuite only.
    #[arg(long, hide = true)]
    pub echo: bool,
    /// Check the settings (flags, environment, --config FILE), print the
    /// effective ones with secrets masked and exit: 0 when usable, 2 with
    /// what is wrong.
    #[arg(long)]
    pub check_config: bool,
    /// The MQTT uplink.
    #[command(flatten)]
    pub uplink: crate::uplink::UplinkCli,
}

/// The config file: every field optional, unknown fields refused.
/// (`--check-config` prints the effective settings in this form.)
#[derive(Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FileConfig {
    /// As `--bind`.
    pub bind: Option<SocketAddr>,
    /// As `--password`.
    pub password: Option<String>,
    /// As `--data-dir`.
    pub data_dir: Option<PathBuf>,
    /// As `--sim-speed`.
    pub sim_speed: Option<f64>,
    /// As `--mavlink`.
    pub mavlink: Option<String>,
    /// As `--mavlink-system`: a number or `"any"`.
    pub mavlink_system: Option<SystemValue>,
    /// As `--mavlink-signing-key`.
    pub mavlink_signing_key: Option<PathBuf>,
    /// As `--min-alt`, m.
    pub min_alt: Option<f64>,
    /// As `--max-alt`, m.
    pub max_alt: Option<f64>,
    /// As `--geofence-radius`, m.
    pub geofence_radius: Option<f64>,
    /// As `--takeoff-alt`, m.
    pub takeoff_alt: Option<f64>,
    /// As `--control-timeout`, in seconds.
    pub control_timeout: Option<u32>,
    /// As `--allow-no-password`.
    pub allow_no_password: Option<bool>,
    /// As `--allow-default-admin`.
    pub allow_default_admin: Option<bool>,
    /// As `--max-message`.
    pub max_message: Option<usize>,
    /// As `--max-connections`.
    pub max_connections: Option<usize>,
    /// As `--max-sessions-per-ip`.
    pub max_sessions_per_ip: Option<usize>,
    /// As `--max-handshakes`.
    pub max_handshakes: Option<usize>,
    /// As `--max-handshakes-per-ip`.
    pub max_handshakes_per_ip: Option<usize>,
    /// As `--handshake-timeout`, in seconds.
    pub handshake_timeout: Option<u64>,
    /// As `--login-timeout`, in seconds.
    pub login_timeout: Option<u64>,
    /// As `--idle-timeout`, in seconds.
    pub idle_timeout: Option<u64>,
    /// As `--login-lockout`, in seconds.
    pub login_lockout: Option<u64>,
    /// As `--login-rate`.
    pub login_rate: Option<u16>,
    /// As `--login-addresses`.
    pub login_addresses: Option<usize>,
    /// As `--allow-origin`, a list.
    pub allow_origin: Option<Vec<String>>,
    /// As `--allow-host`, a list.
    pub allow_host: Option<Vec<String>>,
    /// As `--tls-cert`.
    pub tls_cert: Option<PathBuf>,
    /// As `--tls-key`.
    pub tls_key: Option<PathBuf>,
    /// `false` as `--no-console`.
    pub console: Option<bool>,
    /// The login value that grants admin (protocol default `1025`).
    pub admin_password: Option<String>,
    /// The login value that logs out (protocol default `0315`).
    pub logout_password: Option<String>,
    /// As `--uplink`.
    pub uplink: Option<String>,
    /// As `--uplink-user`.
    pub uplink_user: Option<String>,
    /// As `--uplink-password`.
    pub uplink_password: Option<String>,
    /// As `--uplink-cafile`.
    pub uplink_cafile: Option<PathBuf>,
    /// As `--vehicle-id`.
    pub vehicle_id: Option<String>,
    /// As `--uplink-state-hz`.
    pub uplink_state_hz: Option<f64>,
}

/// `mavlink_system` in the config file: `1` or `"any"`.
#[derive(Debug, Deserialize, Serialize)]
#[serde(untagged)]
pub enum SystemValue {
    /// A system id.
    Id(u16),
    /// `any`.
    Name(String),
}

/// The MAVLink signing key and the file it was read from.
#[derive(Clone, Debug)]
pub struct KeyFile {
    /// The file.
    pub path: PathBuf,
    /// The key.
    pub key: SigningKey,
}

/// Why the settings are unusable.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The config file could not be read.
    #[error("cannot read config file {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The config file is not valid TOML for these settings.
    #[error("invalid config file {path}: {source}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// Why.
        source: Box<toml::de::Error>,
    },
    /// No data directory was given and the platform has no per-user one.
    #[error("no per-user data directory on this system: pass --data-dir")]
    NoDataDir,
    /// A setting is out of range.
    #[error("invalid setting: {0}")]
    Invalid(&'static str),
    /// A MAVLink setting is unusable.
    #[error("invalid setting: {0}")]
    Mavlink(String),
    /// An `--allow-origin` or `--allow-host` value is unusable.
    #[error("invalid setting: {0}")]
    Policy(#[from] crate::net::policy::PolicyError),
}

/// The lockout of an address after 5 wrong passwords, unless configured.
pub const DEFAULT_LOGIN_LOCKOUT: Duration = Duration::from_secs(30);
/// Wrong passwords checked per second across all addresses, unless
/// configured.
pub const DEFAULT_LOGIN_RATE: u16 = 10;
/// Addresses the login lockout remembers, unless configured (about 40
/// bytes each).
pub const DEFAULT_LOGIN_ADDRESSES: usize = 4096;
/// The most `--login-addresses` may ask for (40 MiB of records).
const MAX_LOGIN_ADDRESSES: usize = 1 << 20;

/// The certificate chain and key `wss://` is served with.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TlsFiles {
    /// PEM certificate chain, the server's own first.
    pub cert: PathBuf,
    /// PEM private key.
    pub key: PathBuf,
}

/// Everything `lluavd` runs with, resolved.
#[derive(Clone, Debug)]
pub struct Settings {
    /// Address to listen on.
    pub bind: SocketAddr,
    /// The password from the command line, environment or config file.
    pub password: Option<String>,
    /// The data directory.
    pub data_dir: PathBuf,
    /// Simulation time factor.
    pub sim_speed: f64,
    /// The autopilot's MAVLink address; `None` flies the simulator.
    pub mavlink: Option<String>,
    /// The autopilot followed.
    pub mavlink_system: Wanted,
    /// MAVLink 2 signing.
    pub mavlink_signing_key: Option<KeyFile>,
    /// The MAVLink vehicle's limits (the simulator's are its parameters).
    pub mavlink_limits: FlightLimits,
    /// Whether listening beyond loopback without a password is allowed.
    pub allow_no_password: bool,
    /// Whether listening beyond loopback with the public admin value is allowed.
    pub allow_default_admin: bool,
    /// Connection limits.
    pub limits: Limits,
    /// The Origin/Host policy.
    pub policy: Policy,
    /// `wss://`: the PEM certificate chain and key.
    pub tls: Option<TlsFiles>,
    /// The first lockout of an address after wrong passwords.
    pub login_lockout: Duration,
    /// Wrong passwords checked per second across all addresses.
    pub login_rate: u16,
    /// Addresses the login lockout remembers.
    pub login_addresses: usize,
    /// The admin login value.
    pub admin_password: String,
    /// The logout login value.
    pub logout_password: String,
    /// Serve the browser console to plain HTTP requests.
    pub console: bool,
    /// Serve the echo handler instead of the protocol.
    pub echo: bool,
    /// The MQTT uplink, if configured.
    pub uplink: Option<crate::uplink::Settings>,
}

impl Settings {
    /// Settings from the command line and the config file it names.
    pub fn from_cli(cli: Cli) -> Result<Self, ConfigError> {
        let file = match &cli.config {
            Some(path) => read_file(path)?,
            None => FileConfig::default(),
        };
        Settings::merge(cli, file)
    }

    /// Settings from the command line over `file`.
    pub fn merge(mut cli: Cli, mut file: FileConfig) -> Result<Self, ConfigError> {
        let limits = limits(&cli, &file)?;
        let (login_lockout, login_rate, login_addresses) = login(&cli, &file)?;
        let (mavlink, mavlink_system, mavlink_signing_key) = mavlink(&mut cli, &mut file)?;
        let mavlink_limits = flight_limits(&cli, &file)?;
        let uplink = uplink(cli.uplink, &mut file)?;
        let data_dir = match cli.data_dir.or(file.data_dir) {
            Some(dir) => dir,
            None => directories::ProjectDirs::from("", "", "lluav")
                .ok_or(ConfigError::NoDataDir)?
                .data_dir()
                .to_path_buf(),
        };
        let sim_speed = cli.sim_speed.or(file.sim_speed).unwrap_or(1.0);
        if !(sim_speed.is_finite() && sim_speed > 0.0) {
            return Err(ConfigError::Invalid("--sim-speed must be a finite number > 0"));
        }
        let origins = list(cli.allow_origin, file.allow_origin);
        let policy = Policy::new(&origins, &list(cli.allow_host, file.allow_host))?;
        let tls = match (cli.tls_cert.or(file.tls_cert), cli.tls_key.or(file.tls_key)) {
            (Some(cert), Some(key)) => Some(TlsFiles { cert, key }),
            (None, None) => None,
            _ => return Err(ConfigError::Invalid("--tls-cert and --tls-key go together")),
        };
        Ok(Settings {
            bind: cli.bind.or(file.bind).unwrap_or(DEFAULT_BIND),
            password: cli.password.or(file.password),
            data_dir,
            sim_speed,
            allow_no_password: cli.allow_no_password || file.allow_no_password.unwrap_or(false),
            allow_default_admin: cli.allow_default_admin || file.allow_default_admin.unwrap_or(false),
            limits,
            policy,
            tls,
            login_lockout,
            login_rate,
            login_addresses,
            admin_password: file
                .admin_password
                .unwrap_or_else(|| lluav_core::session::DEFAULT_ADMIN_PASSWORD.to_owned()),
            logout_password: file
                .logout_password
                .unwrap_or_else(|| lluav_core::session::DEFAULT_LOGOUT_PASSWORD.to_owned()),
            console: !cli.no_console && file.console.unwrap_or(true),
            echo: cli.echo,
            mavlink,
            mavlink_system,
            mavlink_signing_key,
            mavlink_limits,
            uplink,
        })
    }
}

/// The radio link, flags over the file (taken from both): the autopilot's
/// address, the autopilot followed and the signing key.
fn mavlink(
    cli: &mut Cli,
    file: &mut FileConfig,
) -> Result<(Option<String>, Wanted, Option<KeyFile>), ConfigError> {
    let address = cli.mavlink.take().or(file.mavlink.take());
    if let Some(address) = &address
        && ::mavlink::ConnectionAddress::parse_address(address).is_err()
    {
        return Err(ConfigError::Invalid(
            "--mavlink must be udpin:HOST:PORT, udpout:HOST:PORT, tcpout:HOST:PORT or serial:DEVICE:BAUD",
        ));
    }
    let wanted = match (cli.mavlink_system, file.mavlink_system.take()) {
        (Some(w), _) => w,
        (None, Some(SystemValue::Id(n))) => n.to_string().parse().map_err(ConfigError::Mavlink)?,
        (None, Some(SystemValue::Name(s))) => s.parse().map_err(ConfigError::Mavlink)?,
        (None, None) => Wanted::default(),
    };
    let key = cli
        .mavlink_signing_key
        .take()
        .or(file.mavlink_signing_key.take())
        .map(|path| SigningKey::read(&path).map(|key| KeyFile { path, key }))
        .transpose()
        .map_err(ConfigError::Mavlink)?;
    Ok((address, wanted, key))
}

/// The MAVLink vehicle's limits: flags over the file over the defaults,
/// each in its range and `min_alt` below `max_alt`.
fn flight_limits(cli: &Cli, file: &FileConfig) -> Result<FlightLimits, ConfigError> {
    let d = FlightLimits::default();
    let limits = FlightLimits {
        min_alt: cli.min_alt.or(file.min_alt).unwrap_or(d.min_alt),
        max_alt: cli.max_alt.or(file.max_alt).unwrap_or(d.max_alt),
        geofence_radius: cli
            .geofence_radius
            .or(file.geofence_radius)
            .unwrap_or(d.geofence_radius),
        takeoff_alt: cli.takeoff_alt.or(file.takeoff_alt).unwrap_or(d.takeoff_alt),
        control_timeout_s: cli
            .control_timeout
            .or(file.control_timeout)
            .unwrap_or(d.control_timeout_s),
    };
    limits.check().map_err(ConfigError::Mavlink)?;
    Ok(limits)
}

/// The login throttle (lockout, attempts per minute, addresses tracked):
/// flags over the file over the defaults.
fn login(cli: &Cli, file: &FileConfig) -> Result<(Duration, u16, usize), ConfigError> {
    let login_lockout = cli
        .login_lockout
        .or(file.login_lockout)
        .map_or(DEFAULT_LOGIN_LOCKOUT, Duration::from_secs);
    if login_lockout.is_zero() {
        return Err(ConfigError::Invalid("--login-lockout must be > 0"));
    }
    let login_rate = cli.login_rate.or(file.login_rate).unwrap_or(DEFAULT_LOGIN_RATE);
    if !(1..=1000).contains(&login_rate) {
        return Err(ConfigError::Invalid("--login-rate must be 1 to 1000"));
    }
    let login_addresses = cli
        .login_addresses
        .or(file.login_addresses)
        .unwrap_or(DEFAULT_LOGIN_ADDRESSES);
    if !(1..=MAX_LOGIN_ADDRESSES).contains(&login_addresses) {
        return Err(ConfigError::Invalid("--login-addresses must be 1 to 1048576"));
    }
    Ok((login_lockout, login_rate, login_addresses))
}

/// A list setting: the command line's, when it gives any, replaces the
/// config file's.
fn list(flag: Vec<String>, key: Option<Vec<String>>) -> Vec<String> {
    if flag.is_empty() {
        key.unwrap_or_default()
    } else {
        flag
    }
}

/// The MQTT uplink: its flags over its keys (taken from `file`).
fn uplink(
    cli: crate::uplink::UplinkCli,
    file: &mut FileConfig,
) -> Result<Option<crate::uplink::Settings>, ConfigError> {
    let keys = crate::uplink::UplinkKeys {
        uplink: file.uplink.take(),
        uplink_user: file.uplink_user.take(),
        uplink_password: file.uplink_password.take(),
        uplink_cafile: file.uplink_cafile.take(),
        vehicle_id: file.vehicle_id.take(),
        uplink_state_hz: file.uplink_state_hz.take(),
    };
    crate::uplink::Settings::resolve(cli, keys).map_err(ConfigError::Invalid)
}

/// The connection limits: flags over the file over the defaults.
fn limits(cli: &Cli, file: &FileConfig) -> Result<Limits, ConfigError> {
    let defaults = Limits::default();
    let secs = |flag: Option<u64>, key: Option<u64>, default: Duration| {
        flag.or(key).map_or(default, Duration::from_secs)
    };
    let limits = Limits {
        max_message: cli
            .max_message
            .or(file.max_message)
            .unwrap_or(defaults.max_message),
        max_connections: cli
            .max_connections
            .or(file.max_connections)
            .unwrap_or(defaults.max_connections),
        max_sessions_per_ip: cli
            .max_sessions_per_ip
            .or(file.max_sessions_per_ip)
            .unwrap_or(defaults.max_sessions_per_ip),
        max_handshakes: cli
            .max_handshakes
            .or(file.max_handshakes)
            .unwrap_or(defaults.max_handshakes),
        max_handshakes_per_ip: cli
            .max_handshakes_per_ip
            .or(file.max_handshakes_per_ip)
            .unwrap_or(defaults.max_handshakes_per_ip),
        handshake_timeout: secs(
            cli.handshake_timeout,
            file.handshake_timeout,
            defaults.handshake_timeout,
        ),
        login_timeout: secs(cli.login_timeout, file.login_timeout, defaults.login_timeout),
        idle_timeout: secs(cli.idle_timeout, file.idle_timeout, defaults.idle_timeout),
        ..defaults
    };
    let positive = [
        (limits.max_message == 0, "--max-message must be > 0"),
        (limits.max_connections == 0, "--max-connections must be > 0"),
        (
            limits.max_sessions_per_ip == 0,
            "--max-sessions-per-ip must be > 0",
        ),
        (limits.max_handshakes == 0, "--max-handshakes must be > 0"),
        (
            limits.max_handshakes_per_ip == 0,
            "--max-handshakes-per-ip must be > 0",
        ),
        (
            limits.handshake_timeout.is_zero(),
            "--handshake-timeout must be > 0",
        ),
        (limits.login_timeout.is_zero(), "--login-timeout must be > 0"),
        (limits.idle_timeout.is_zero(), "--idle-timeout must be > 0"),
    ];
    match positive.iter().find(|(zero, _)| *zero) {
        Some((_, why)) => Err(ConfigError::Invalid(why)),
        None => Ok(limits),
    }
}

fn read_file(path: &Path) -> Result<FileConfig, ConfigError> {
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
        path: path.to_owned(),
        source,
    })?;
    toml::from_str(&text).map_err(|source| ConfigError::Parse {
        path: path.to_owned(),
        source: Box::new(source),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cli(args: &[&str]) -> Cli {
        Cli::try_parse_from(std::iter::once("lluavd").chain(args.iter().copied()))
            .expect("valid command line")
    }

    #[test]
    fn flags_win_over_the_config_file() {
        let file: FileConfig = toml::from_str("bind = \"0.0.0.0:1\"\nsim_speed = 3.0\nmax_connections = 9\n")
            .expect("valid TOML");
        let s =
            Settings::merge(cli(&["--bind", "127.0.0.1:0", "--data-dir", "/tmp/x"]), file).expect("valid");
        assert_eq!(s.bind, "127.0.0.1:0".parse().expect("address"));
        assert_eq!(s.sim_speed, 3.0);
        assert_eq!(s.limits.max_connections, 9);
        assert_eq!(s.limits.max_message, 64 * 1024);
    }

    #[test]
    fn defaults_are_loopback_and_the_protocol_port() {
        let s = Settings::merge(cli(&["--data-dir", "/tmp/x"]), FileConfig::default()).expect("valid");
        assert_eq!(s.bind, DEFAULT_BIND);
        assert_eq!(s.admin_password, "1025");
        assert_eq!(s.logout_password, "0315");
        assert!(!s.allow_no_password && !s.allow_default_admin);
        assert!(s.console);
        assert_eq!((s.login_rate, s.login_addresses), (10, 4096));
    }

    #[test]
    fn console_is_off_by_flag_or_config_key() {
        let off: FileConfig = toml::from_str("console = false").expect("valid TOML");
        let on: FileConfig = toml::from_str("console = true").expect("valid TOML");
        let dir = ["--data-dir", "/tmp/x"];
        assert!(!Settings::merge(cli(&dir), off).expect("valid").console);
        assert!(Settings::merge(cli(&dir), on).expect("valid").console);
        let flag = cli(&["--no-console", "--data-dir", "/tmp/x"]);
        let on: FileConfig = toml::from_str("console = true").expect("valid TOML");
        assert!(!Settings::merge(flag, on).expect("valid").console);
    }

    #[test]
    fn network_limits_and_lists_come_from_flags_over_the_file() {
        let file: FileConfig = toml::from_str(
            "max_sessions_per_ip = 3\nlogin_timeout = 7\nallow_host = [\"drone.local\"]\n\
             allow_origin = [\"https://gcs.example\"]\nlogin_lockout = 5\nlogin_rate = 3\n\
             login_addresses = 100\n",
        )
        .expect("valid TOML");
        let s = Settings::merge(
            cli(&[
                "--data-dir",
                "/tmp/x",
                "--max-sessions-per-ip",
                "4",
                "--handshake-timeout",
                "2",
                "--login-addresses",
                "50",
            ]),
            file,
        )
        .expect("valid");
        assert_eq!(s.limits.max_sessions_per_ip, 4);
        assert_eq!(s.limits.login_timeout, Duration::from_secs(7));
        assert_eq!(s.limits.handshake_timeout, Duration::from_secs(2));
        assert_eq!(s.login_lockout, Duration::from_secs(5));
        assert_eq!((s.login_rate, s.login_addresses), (3, 50));
        let loopback = std::net::IpAddr::V4(Ipv4Addr::LOCALHOST);
        assert!(
            s.policy
                .at(loopback, true)
                .check("drone.local", Some("https://gcs.example"))
                .is_ok()
        );
        assert!(s.tls.is_none());
    }

    #[test]
    fn unusable_network_settings_are_refused() {
        let refused = |args: &[&str], file: &str| {
            let mut all = vec!["--data-dir", "/tmp/x"];
            all.extend_from_slice(args);
            let file: FileConfig = toml::from_str(file).expect("valid TOML");
            Settings::merge(cli(&all), file).is_err()
        };
        assert!(refused(&["--allow-origin", "evil.example"], ""));
        assert!(refused(&["--allow-host", "drone.local:80"], ""));
        assert!(refused(&["--max-sessions-per-ip", "0"], ""));
        assert!(refused(&["--login-timeout", "0"], ""));
        assert!(refused(&["--login-rate", "0"], ""));
        assert!(refused(&[], "login_rate = 1001"));
        assert!(refused(&["--login-addresses", "0"], ""));
        assert!(
            refused(&[], "tls_cert = \"cert.pem\""),
            "a certificate needs its key"
        );
        assert!(Cli::try_parse_from(["lluavd", "--tls-key", "key.pem"]).is_err());
    }

    #[test]
    fn unknown_config_fields_are_refused() {
        assert!(toml::from_str::<FileConfig>("pasword = \"x\"").is_err());
    }

    #[test]
    fn a_mavlink_address_outside_the_crates_syntax_is_refused() {
        let ok = Settings::merge(
            cli(&["--mavlink", "udpin:0.0.0.0:14540", "--data-dir", "/tmp/x"]),
            FileConfig::default(),
        )
        .expect("valid");
        assert_eq!(ok.mavlink.as_deref(), Some("udpin:0.0.0.0:14540"));
        let err = Settings::merge(
            cli(&["--mavlink", "/dev/ttyACM0", "--data-dir", "/tmp/x"]),
            FileConfig::default(),
        );
        assert!(matches!(err, Err(ConfigError::Invalid(_))));
    }

    #[test]
    fn the_followed_autopilot_and_the_signing_key_come_from_the_flags_over_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let key = dir.path().join("key");
        std::fs::write(&key, format!("{}\n", "ab".repeat(32))).unwrap();
        let file: FileConfig = toml::from_str("mavlink_system = \"any\"").unwrap();
        let s = Settings::merge(cli(&["--data-dir", "/tmp/x"]), file).unwrap();
        assert_eq!(s.mavlink_system, Wanted::Any);
        assert!(s.mavlink_signing_key.is_none());
        let file: FileConfig = toml::from_str("mavlink_system = 3").unwrap();
        let key_flag = key.to_str().unwrap();
        let s = Settings::merge(
            cli(&["--data-dir", "/tmp/x", "--mavlink-signing-key", key_flag]),
            file,
        )
        .unwrap();
        assert_eq!(s.mavlink_system, Wanted::System(3));
        assert!(s.mavlink_signing_key.is_some());
        let file: FileConfig = toml::from_str("mavlink_system = 3").unwrap();
        let s = Settings::merge(cli(&["--data-dir", "/tmp/x", "--mavlink-system", "7"]), file).unwrap();
        assert_eq!(s.mavlink_system, Wanted::System(7));
        let s = Settings::merge(cli(&["--data-dir", "/tmp/x"]), FileConfig::default()).unwrap();
        assert_eq!(s.mavlink_system, Wanted::System(1));
        for bad in [
            "mavlink_system = 0",
            "mavlink_system = 256",
            "mavlink_system = \"all\"",
        ] {
            let file: FileConfig = toml::from_str(bad).unwrap();
            let err = Settings::merge(cli(&["--data-dir", "/tmp/x"]), file);
            assert!(matches!(err, Err(ConfigError::Mavlink(_))), "{bad}");
        }
        std::fs::write(&key, "abcd").unwrap();
        let err = Settings::merge(
            cli(&["--data-dir", "/tmp/x", "--mavlink-signing-key", key_flag]),
            FileConfig::default(),
        );
        assert!(matches!(err, Err(ConfigError::Mavlink(e)) if e.contains("64 hex digits")));
    }

    #[test]
    fn the_mavlink_vehicles_limits_come_from_the_flags_over_the_file_in_range() {
        let s = Settings::merge(cli(&["--data-dir", "/tmp/x"]), FileConfig::default()).unwrap();
        assert_eq!(s.mavlink_limits, FlightLimits::default());
        assert_eq!(
            (
                s.mavlink_limits.min_alt,
                s.mavlink_limits.max_alt,
                s.mavlink_limits.geofence_radius
            ),
            (0.5, 120.0, 500.0)
        );
        assert_eq!(
            (s.mavlink_limits.takeoff_alt, s.mavlink_limits.control_timeout_s),
            (2.5, 30)
        );
        let file: FileConfig = toml::from_str(
            "max_alt = 30.0\ngeofence_radius = 80.0\ntakeoff_alt = 5.0\ncontrol_timeout = 12\n",
        )
        .unwrap();
        let s = Settings::merge(
            cli(&["--data-dir", "/tmp/x", "--max-alt", "20", "--min-alt", "1"]),
            file,
        )
        .unwrap();
        let l = s.mavlink_limits;
        assert_eq!((l.min_alt, l.max_alt, l.geofence_radius), (1.0, 20.0, 80.0));
        assert_eq!((l.takeoff_alt, l.control_timeout_s), (5.0, 12));
        // A takeoff altitude above max_alt is clipped when flown, not refused.
        let file: FileConfig = toml::from_str("max_alt = 3.0\ntakeoff_alt = 5.0").unwrap();
        assert!(Settings::merge(cli(&["--data-dir", "/tmp/x"]), file).is_ok());
        for (bad, why) in [
            ("min_alt = 0.1", "min_alt 0.1 out of range 0.2..10"),
            ("max_alt = 501.0", "max_alt 501 out of range 1..500"),
            (
                "geofence_radius = 0.5",
                "geofence_radius 0.5 out of range 1..10000",
            ),
            ("takeoff_alt = 121.0", "takeoff_alt 121 out of range 0.5..120"),
            ("control_timeout = 0", "control_timeout 0 out of range 1..3600"),
            ("max_alt = nan", "max_alt NaN out of range 1..500"),
            (
                "min_alt = 5.0\nmax_alt = 5.0",
                "min_alt 5 m not below max_alt 5 m: no altitude would be left to fly",
            ),
        ] {
            let file: FileConfig = toml::from_str(bad).unwrap();
            let err = Settings::merge(cli(&["--data-dir", "/tmp/x"]), file);
            assert!(
                matches!(&err, Err(ConfigError::Mavlink(e)) if e == why),
                "{bad}: {err:?}"
            );
        }
    }

    #[test]
    fn non_positive_sim_speed_is_refused() {
        let err = Settings::merge(
            cli(&["--sim-speed", "0", "--data-dir", "/tmp/x"]),
            FileConfig::default(),
        );
        assert!(matches!(err, Err(ConfigError::Invalid(_))));
    }
}
