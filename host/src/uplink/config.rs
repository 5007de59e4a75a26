//! The uplink's settings: `--uplink URL` and the flags and config keys
//! that go with it (DESIGN.md, "Uplink").

use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;

use clap::Args;

use super::topic::{sanitize, valid_name};

/// The highest `--uplink-state-hz`.
pub const MAX_STATE_HZ: f64 = 10.0;

/// A broker's address: `mqtt://HOST[:PORT]` (1883) or `mqtts://HOST[:PORT]`
/// (8883, TLS).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BrokerUrl {
    /// `mqtts://`.
    pub tls: bool,
    /// The host name or address (an IPv6 address without its brackets).
    pub host: String,
    /// The port.
    pub port: u16,
}

/// Why a broker URL is unusable.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("a broker URL is mqtt://HOST[:PORT] or mqtts://HOST[:PORT]")]
pub struct BadUrl;

impl FromStr for BrokerUrl {
    type Err = BadUrl;

    fn from_str(url: &str) -> Result<Self, BadUrl> {
        let (tls, rest) = if let Some(rest) = url.strip_prefix("mqtts://") {
            (true, rest)
        } else if let Some(rest) = url.strip_prefix("mqtt://") {
            (false, rest)
        } else {
            return Err(BadUrl);
        };
        let rest = rest.strip_suffix('/').unwrap_or(rest);
        let (host, port) = if let Some(v6) = rest.strip_prefix('[') {
            let (host, after) = v6.split_once(']').ok_or(BadUrl)?;
            (host, after.strip_prefix(':'))
        } else {
            match rest.split_once(':') {
                Some((host, port)) => (host, Some(port)),
                None => (rest, None),
            }
        };
        let port = match port {
            Some(p) => p.parse().map_err(|_| BadUrl)?,
            None if tls => 8883,
            None => 1883,
        };
        let bad_host = host.is_empty() || host.contains(['/', '@', '?', '#', ' ', '[', ']']);
        if bad_host || port == 0 {
            return Err(BadUrl);
        }
        Ok(BrokerUrl {
            tls,
            host: host.to_owned(),
            port,
        })
    }
}

impl fmt::Display for BrokerUrl {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let scheme = if self.tls { "mqtts" } else { "mqtt" };
        if self.host.contains(':') {
            write!(f, "{scheme}://[{}]:{}", self.host, self.port)
        } else {
            write!(f, "{scheme}://{}:{}", self.host, self.port)
        }
    }
}

/// `lluavd`'s uplink flags.
#[derive(Clone, Debug, Default, Args)]
pub struct UplinkCli {
    /// Serve the protocol through an MQTT broker too (vehicles behind NAT,
    /// fleets): mqtt://HOST or mqtt://HOST:PORT (1883), mqtts://... for TLS (8883).
    #[arg(long, value_name = "URL")]
    pub uplink: Option<String>,
    /// The user name at the broker.
    #[arg(long, value_name = "USER")]
    pub uplink_user: Option<String>,
    /// The password at the broker.
    #[arg(
        long,
        env = "LLUAV_UPLINK_PASSWORD",
        hide_env_values = true,
        value_name = "PASS"
    )]
    pub uplink_password: Option<String>,
    /// For mqtts:// brokers with a private CA: a PEM file of the
    /// certificates to trust instead of the system's.
    #[arg(long, value_name = "FILE")]
    pub uplink_cafile: Option<PathBuf>,
    /// This vehicle's id in topics: 1-64 of [A-Za-z0-9_-]; with
    /// --uplink-user it is that user name. [default: the broker user name,
    /// else the host name]
    #[arg(long, value_name = "ID")]
    pub vehicle_id: Option<String>,
    /// How often the state is published to the broker; 0: only when fsm,
    /// armed or link change (it is published on every change anyway);
    /// at most 10. [default: 1]
    #[arg(long, value_name = "HZ")]
    pub uplink_state_hz: Option<f64>,
}

/// The uplink's config file keys, each as its flag.
#[derive(Clone, Debug, Default)]
pub struct UplinkKeys {
    /// `uplink`.
    pub uplink: Option<String>,
    /// `uplink_user`.
    pub uplink_user: Option<String>,
    /// `uplink_password`.
    pub uplink_password: Option<String>,
    /// `uplink_cafile`.
    pub uplink_cafile: Option<PathBuf>,
    /// `vehicle_id`.
    pub vehicle_id: Option<String>,
    /// `uplink_state_hz`.
    pub uplink_state_hz: Option<f64>,
}

/// The uplink, resolved.
#[derive(Clone, Debug, PartialEq)]
pub struct Settings {
    /// The broker.
    pub broker: BrokerUrl,
    /// The user name at the broker.
    pub user: Option<String>,
    /// The password at the broker.
    pub password: Option<String>,
    /// CA certificates for `mqtts://`, instead of the system's.
    pub cafile: Option<PathBuf>,
    /// The vehicle's id in topics.
    pub vehicle_id: String,
    /// State publications per second; 0: only on change.
    pub state_hz: f64,
}

impl Settings {
    /// The uplink from the flags over the config keys; `None` without a
    /// broker URL.
    pub fn resolve(cli: UplinkCli, file: UplinkKeys) -> Result<Option<Settings>, &'static str> {
        let Some(url) = cli.uplink.or(file.uplink) else {
            return Ok(None);
        };
        let broker: BrokerUrl = url
            .parse()
            .map_err(|_| "--uplink must be mqtt://HOST[:PORT] or mqtts://HOST[:PORT]")?;
        let cafile = cli.uplink_cafile.or(file.uplink_cafile);
        if cafile.is_some() && !broker.tls {
            return Err("--uplink-cafile is for mqtts:// brokers");
        }
        let user = cli.uplink_user.or(file.uplink_user);
        // The broker account is the identity: its user name is the
        // vehicle's id in topics and its client id, so that the ACL block
        // of that account is the vehicle's.
        let vehicle_id = match (cli.vehicle_id.or(file.vehicle_id), &user) {
            (Some(id), _) if !valid_name(&id) => return Err("--vehicle-id must be 1-64 of [A-Za-z0-9_-]"),
            (Some(id), Some(user)) if id != *user => {
                return Err("--vehicle-id must be the broker user name (--uplink-user) when one is given");
            }
            (Some(id), _) => id,
            (None, Some(user)) if valid_name(user) => user.clone(),
            (None, Some(_)) => {
                return Err(
                    "the vehicle id is the broker user name (--uplink-user), which must then be 1-64 of \
                     [A-Za-z0-9_-]",
                );
            }
            (None, None) => default_vehicle_id(),
        };
        let state_hz = cli.uplink_state_hz.or(file.uplink_state_hz).unwrap_or(1.0);
        if !(0.0..=MAX_STATE_HZ).contains(&state_hz) {
            return Err("--uplink-state-hz must be a number from 0 to 10");
        }
        Ok(Some(Settings {
            broker,
            user,
            password: cli.uplink_password.or(file.uplink_password),
            cafile,
            vehicle_id,
            state_hz,
        }))
    }
}

impl Settings {
    /// The vehicle's MQTT client id: its broker user name (the broker may
    /// force it to be: `use_username_as_clientid`), or `lluavd-<V>`.
    pub fn client_id(&self) -> String {
        self.user
            .clone()
            .unwrap_or_else(|| format!("lluavd-{}", self.vehicle_id))
    }
}

/// The host name, made a valid vehicle id.
fn default_vehicle_id() -> String {
    let host = nix::unistd::gethostname()
        .ok()
        .and_then(|h| h.into_string().ok())
        .unwrap_or_default();
    sanitize(&host, "lluavd")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn broker_urls_take_a_host_and_an_optional_port() {
        let url = |s: &str| s.parse::<BrokerUrl>();
        let b = url("mqtt://broker.example").expect("valid");
        assert_eq!((b.tls, b.host.as_str(), b.port), (false, "broker.example", 1883));
        let b = url("mqtts://10.0.0.1:8884/").expect("valid");
        assert_eq!((b.tls, b.host.as_str(), b.port), (true, "10.0.0.1", 8884));
        let b = url("mqtts://[::1]").expect("valid");
        assert_eq!((b.host.as_str(), b.port), ("::1", 8883));
        assert_eq!(b.to_string(), "mqtts://[::1]:8883");
        for bad in [
            "tcp://h",
            "mqtt://",
            "mqtt://h:0",
            "mqtt://h:x",
            "mqtt://u@h",
            "mqtt://h/x",
            "h:1883",
        ] {
            assert!(url(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn flags_win_over_keys_and_bad_values_are_refused() {
        let keys = UplinkKeys {
            uplink: Some("mqtt://file".into()),
            vehicle_id: Some("from-file".into()),
            uplink_state_hz: Some(0.2),
            ..UplinkKeys::default()
        };
        let cli = UplinkCli {
            uplink: Some("mqtt://flag:1884".into()),
            ..UplinkCli::default()
        };
        let s = Settings::resolve(cli, keys.clone())
            .expect("valid")
            .expect("configured");
        assert_eq!(s.broker.host, "flag");
        assert_eq!(s.vehicle_id, "from-file");
        assert_eq!(s.state_hz, 0.2);
        assert_eq!(
            Settings::resolve(UplinkCli::default(), UplinkKeys::default()),
            Ok(None)
        );
        let refused = |cli: UplinkCli| Settings::resolve(cli, keys.clone()).is_err();
        assert!(refused(UplinkCli {
            vehicle_id: Some("a/b".into()),
            ..UplinkCli::default()
        }));
        assert!(refused(UplinkCli {
            uplink_state_hz: Some(10.5),
            ..UplinkCli::default()
        }));
        assert!(refused(UplinkCli {
            uplink_state_hz: Some(f64::NAN),
            ..UplinkCli::default()
        }));
        assert!(refused(UplinkCli {
            uplink_cafile: Some("ca.pem".into()),
            ..UplinkCli::default()
        }));
        let default = Settings::resolve(
            UplinkCli {
                uplink: Some("mqtt://h".into()),
                ..UplinkCli::default()
            },
            UplinkKeys::default(),
        );
        assert!(valid_name(
            &default.expect("valid").expect("configured").vehicle_id
        ));
    }

    #[test]
    fn the_broker_user_name_is_the_vehicle_id_and_its_client_id() {
        let resolve = |user: Option<&str>, id: Option<&str>| {
            let cli = UplinkCli {
                uplink: Some("mqtt://h".into()),
                uplink_user: user.map(str::to_owned),
                vehicle_id: id.map(str::to_owned),
                ..UplinkCli::default()
            };
            Settings::resolve(cli, UplinkKeys::default())
                .map(|s| s.map(|s| (s.vehicle_id.clone(), s.client_id())))
        };
        assert_eq!(
            resolve(Some("drone-1"), None),
            Ok(Some(("drone-1".into(), "drone-1".into())))
        );
        assert_eq!(
            resolve(Some("drone-1"), Some("drone-1")),
            Ok(Some(("drone-1".into(), "drone-1".into())))
        );
        assert_eq!(
            resolve(None, Some("v7")),
            Ok(Some(("v7".into(), "lluavd-v7".into())))
        );
        let other = resolve(Some("drone-1"), Some("drone-2")).expect_err("another account's id");
        assert!(other.contains("--uplink-user"), "{other}");
        let invalid = resolve(Some("drone.1"), None).expect_err("not an id");
        assert!(invalid.contains("[A-Za-z0-9_-]"), "{invalid}");
    }
}
