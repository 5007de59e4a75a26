//! `lluavd --check-config`: the settings are resolved and checked as the
//! daemon would at start (the config file's keys, ranges, the password
//! rules, the TLS files), without binding or opening anything, then printed
//! as a config file would say them, every key in [`FileConfig`]'s order,
//! secrets masked.
//!
//! The printout covers every key the config file accepts: the keys come
//! from [`FileConfig`]'s own deserializer ([`keys`]), and [`effective`]
//! names every field, so a key added to the file without a value here does
//! not compile, and one without a line in the packaged config file fails
//! the service tests.

use std::fmt::Write as _;
use std::process::ExitCode;

use serde::Deserialize as _;
use serde::de::{self, Visitor};

use crate::config::{Cli, ConfigError, FileConfig, Settings, SystemValue};
use crate::daemon::{self, DaemonError};
use crate::mavlink::Wanted;

/// What a masked secret is printed as.
pub const MASK: &str = "********";

/// Words that make a key's value a secret.
const SECRET_WORDS: [&str; 4] = ["password", "secret", "token", "signing_key"];

/// Runs the check for `cli`: prints the effective settings to stdout and
/// answers 0, or prints what is wrong to stderr and answers 2.
pub fn run(cli: Cli) -> ExitCode {
    let source = cli.config.as_ref().map(|p| p.display().to_string());
    let checked = Settings::from_cli(cli).map_err(CheckError::Config).and_then(|s| {
        check(&s)?;
        Ok(s)
    });
    match checked {
        Ok(settings) => {
            let from = source.map_or_else(|| "no config file".to_owned(), |f| format!("config file {f}"));
            println!("# lluavd's effective settings (flags, then {from}, then defaults); secrets masked");
            print!("{}", render(&settings));
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("lluavd: {e}");
            ExitCode::from(2)
        }
    }
}

/// Why `--check-config` refused the settings.
#[derive(Debug, thiserror::Error)]
pub enum CheckError {
    /// The flags or the config file.
    #[error(transparent)]
    Config(ConfigError),
    /// What the daemon would refuse at start.
    #[error(transparent)]
    Daemon(#[from] DaemonError),
}

/// What the daemon checks at start without side effects: the password
/// rules and the TLS files. A missing password beyond loopback is only
/// reported on stderr: `passwd` may have stored one in the data directory.
/// The public admin value is refused whatever the password.
pub fn check(settings: &Settings) -> Result<(), CheckError> {
    if let Some(refused) = daemon::refusal(settings, true) {
        return Err(refused.into());
    }
    match daemon::auth(settings, None) {
        Err(DaemonError::NoPassword(addr)) => {
            eprintln!(
                "lluavd: note: no password is configured and {addr} is beyond loopback: lluavd will \
                 refuse to start unless `passwd` stored one in the data directory"
            );
        }
        Err(DaemonError::UplinkNoPassword) => {
            eprintln!(
                "lluavd: note: no password is configured and the uplink is on: lluavd will refuse to \
                 start unless `passwd` stored one in the data directory"
            );
        }
        other => {
            other?;
        }
    }
    if let Some(uplink) = settings.uplink.as_ref().filter(|u| u.broker.tls) {
        crate::client::tls_config(uplink.cafile.as_deref()).map_err(DaemonError::Uplink)?;
    }
    if let Some(files) = &settings.tls {
        crate::net::tls::acceptor(&files.cert, &files.key, std::time::SystemTime::now())
            .map_err(DaemonError::from)?;
    }
    Ok(())
}

/// The config file's keys, in declaration order, as its deserializer
/// knows them.
pub fn keys() -> &'static [&'static str] {
    let mut probe = KeyProbe(None);
    // The probe refuses every value: only the keys it was shown matter.
    let _ = FileConfig::deserialize(&mut probe);
    probe.0.unwrap_or_default()
}

/// A deserializer that records the field names of the struct asked of it.
struct KeyProbe(Option<&'static [&'static str]>);

impl<'de> de::Deserializer<'de> for &mut KeyProbe {
    type Error = de::value::Error;

    fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Self::Error> {
        Err(de::Error::custom("only the keys are read"))
    }

    fn deserialize_struct<V: Visitor<'de>>(
        self,
        _: &'static str,
        fields: &'static [&'static str],
        _: V,
    ) -> Result<V::Value, Self::Error> {
        self.0 = Some(fields);
        Err(de::Error::custom("only the keys are read"))
    }

    serde::forward_to_deserialize_any! {
        bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes byte_buf option
        unit unit_struct newtype_struct seq tuple tuple_struct map enum identifier ignored_any
    }
}

/// The settings as a config file that says every one of them.
pub fn effective(s: &Settings) -> FileConfig {
    let l = &s.limits;
    FileConfig {
        bind: Some(s.bind),
        password: s.password.clone(),
        data_dir: Some(s.data_dir.clone()),
        sim_speed: Some(s.sim_speed),
        mavlink: s.mavlink.clone(),
        mavlink_system: Some(match s.mavlink_system {
            Wanted::System(n) => SystemValue::Id(n.into()),
            Wanted::Any => SystemValue::Name("any".into()),
        }),
        mavlink_signing_key: s.mavlink_signing_key.as_ref().map(|k| k.path.clone()),
        min_alt: Some(s.mavlink_limits.min_alt),
        max_alt: Some(s.mavlink_limits.max_alt),
        geofence_radius: Some(s.mavlink_limits.geofence_radius),
        takeoff_alt: Some(s.mavlink_limits.takeoff_alt),
        control_timeout: Some(s.mavlink_limits.control_timeout_s),
        allow_no_password: Some(s.allow_no_password),
        allow_default_admin: Some(s.allow_default_admin),
        max_message: Some(l.max_message),
        max_connections: Some(l.max_connections),
        max_sessions_per_ip: Some(l.max_sessions_per_ip),
        max_handshakes: Some(l.max_handshakes),
        max_handshakes_per_ip: Some(l.max_handshakes_per_ip),
        handshake_timeout: Some(l.handshake_timeout.as_secs()),
        login_timeout: Some(l.login_timeout.as_secs()),
        idle_timeout: Some(l.idle_timeout.as_secs()),
        login_lockout: Some(s.login_lockout.as_secs()),
        login_rate: Some(s.login_rate),
        login_addresses: Some(s.login_addresses),
        allow_origin: Some(s.policy.origins()),
        allow_host: Some(s.policy.hosts()),
        tls_cert: s.tls.as_ref().map(|t| t.cert.clone()),
        tls_key: s.tls.as_ref().map(|t| t.key.clone()),
        console: Some(s.console),
        admin_password: Some(s.admin_password.clone()),
        logout_password: Some(s.logout_password.clone()),
        uplink: s.uplink.as_ref().map(|u| u.broker.to_string()),
        uplink_user: s.uplink.as_ref().and_then(|u| u.user.clone()),
        uplink_password: s.uplink.as_ref().and_then(|u| u.password.clone()),
        uplink_cafile: s.uplink.as_ref().and_then(|u| u.cafile.clone()),
        vehicle_id: s.uplink.as_ref().map(|u| u.vehicle_id.clone()),
        uplink_state_hz: s.uplink.as_ref().map(|u| u.state_hz),
    }
}

/// Whether `key`'s value is a secret.
pub fn is_secret(key: &str) -> bool {
    SECRET_WORDS.iter().any(|w| key.contains(w))
}

/// One `key = value` line per key (`# key: not set` for a key without a
/// value). A secret is masked unless it is the built-in default, which is
/// no secret (the protocol's public `1025`, for one).
pub fn render(settings: &Settings) -> String {
    let table = |s: &Settings| toml::Table::try_from(effective(s)).unwrap_or_default();
    let now = table(settings);
    let defaults = Settings::merge(Cli::default(), FileConfig::default())
        .map(|d| table(&d))
        .unwrap_or_default();
    let mut out = String::new();
    for key in keys() {
        let _ = match now.get(*key) {
            None => writeln!(out, "# {key}: not set"),
            Some(v) if is_secret(key) && defaults.get(*key) != Some(v) => writeln!(out, "{key} = \"{MASK}\""),
            Some(v) => writeln!(out, "{key} = {v}"),
        };
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser as _;

    fn settings(file: &str) -> Settings {
        let cli = Cli::try_parse_from(["lluavd", "--data-dir", "/tmp/x"]).expect("valid command line");
        Settings::merge(cli, toml::from_str(file).expect("valid TOML")).expect("valid settings")
    }

    #[test]
    fn every_key_of_the_file_is_printed_once_in_its_order() {
        let printed = render(&settings(""));
        let names: Vec<&str> = printed
            .lines()
            .map(|l| l.trim_start_matches("# ").split([' ', ':']).next().unwrap_or(""))
            .collect();
        assert_eq!(names, keys());
        assert!(keys().contains(&"bind") && keys().contains(&"logout_password"));
    }

    #[test]
    fn the_printout_is_a_config_file_giving_the_same_settings() {
        let file = "bind = \"0.0.0.0:9\"\nallow_origin = [\"https://gcs.example\"]\nconsole = false\n\
                    allow_host = [\"drone.local\"]\ntls_cert = \"c.pem\"\ntls_key = \"k.pem\"\n";
        let first = render(&settings(file));
        assert_eq!(render(&settings(&first)), first);
        assert!(
            first.contains("allow_origin = [\"https://gcs.example\"]"),
            "{first}"
        );
        assert!(first.contains("\n# password: not set\n"), "{first}");
    }

    #[test]
    fn secrets_are_masked_unless_they_are_the_defaults() {
        let printed = render(&settings("password = \"hunter22\"\nlogout_password = \"9999\"\n"));
        assert!(
            !printed.contains("hunter22") && !printed.contains("9999"),
            "{printed}"
        );
        assert!(printed.contains(&format!("password = \"{MASK}\"")), "{printed}");
        assert!(printed.contains("admin_password = \"1025\""), "{printed}");
    }

    #[test]
    fn the_uplink_with_the_public_admin_value_is_refused_and_says_why() {
        let uplink = "uplink = \"mqtt://broker.example\"\nvehicle_id = \"v1\"\npassword = \"pw-1234\"\n";
        let refused = check(&settings(uplink)).expect_err("the public admin value through a broker");
        let why = refused.to_string();
        assert!(
            why.contains("--uplink")
                && why.contains("admin_password")
                && why.contains("--allow-default-admin"),
            "{why}"
        );
        // Without a password too: the admin rule is not a note.
        let no_password =
            "uplink = \"mqtt://broker.example\"\nvehicle_id = \"v1\"\nallow_no_password = true\n";
        assert!(check(&settings(no_password)).is_err());
        assert!(check(&settings(&format!("{uplink}admin_password = \"adm-4711\"\n"))).is_ok());
        assert!(check(&settings(&format!("{uplink}allow_default_admin = true\n"))).is_ok());
        // Loopback without an uplink keeps the spec's value.
        assert!(check(&settings("password = \"pw-1234\"\n")).is_ok());
    }
}
