//! The operator's allow-lists for the `Origin` and `Host` rules
//! (`--allow-origin`, `--allow-host`), checked at start. The rules are the
//! core's ([`lluav_core::websocket::policy`]), the same as the MCU's:
//! lluavd brings the lists, and per connection the address it arrived on
//! and whether it is TLS.

use std::net::IpAddr;

use lluav_core::websocket::policy::{self, valid_host_name, valid_origin};

/// A value of `--allow-origin` or `--allow-host` that cannot be used.
#[derive(Debug, thiserror::Error)]
#[error("{what} `{value}`: {why}")]
pub struct PolicyError {
    what: &'static str,
    value: String,
    why: &'static str,
}

/// The operator's allow-lists, checked against every upgrade.
#[derive(Clone, Debug, Default)]
pub struct Policy {
    origins: Vec<String>,
    hosts: Vec<String>,
}

impl Policy {
    /// A policy allowing `origins` (URLs such as `https://gcs.example:8443`,
    /// or `*` for any) and the extra `Host` names `hosts` (`drone.local`).
    pub fn new(origins: &[String], hosts: &[String]) -> Result<Policy, PolicyError> {
        let refuse = |what, value: &String, why| PolicyError {
            what,
            value: value.clone(),
            why,
        };
        if let Some(bad) = origins.iter().find(|o| !valid_origin(o)) {
            let why = "not an origin such as https://gcs.example:8443 (or * for any)";
            return Err(refuse("--allow-origin", bad, why));
        }
        if let Some(bad) = hosts.iter().find(|h| !valid_host_name(h)) {
            let why = "not a host name such as drone.local (without a port)";
            return Err(refuse("--allow-host", bad, why));
        }
        Ok(Policy {
            origins: origins.to_vec(),
            hosts: hosts.to_vec(),
        })
    }

    /// The allowed origins as `--allow-origin` took them (`*` for any).
    pub fn origins(&self) -> Vec<String> {
        self.origins.clone()
    }

    /// The extra host names allowed in `Host`.
    pub fn hosts(&self) -> Vec<String> {
        self.hosts.clone()
    }

    /// The rules for a connection that arrived on `local` (`tls`: `wss://`;
    /// an IPv4 client of a socket bound to `[::]` arrives on an
    /// IPv4-mapped address).
    pub fn at(&self, local: IpAddr, tls: bool) -> policy::Policy<'_, String> {
        policy::Policy {
            local: local.to_canonical(),
            tls,
            allowed_origins: &self.origins,
            allowed_hosts: &self.hosts,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unusable_allow_list_entries_are_refused_at_start() {
        assert!(Policy::new(&["evil.example".into()], &[]).is_err());
        assert!(Policy::new(&["ftp://x".into()], &[]).is_err());
        assert!(Policy::new(&["http://x/path".into()], &[]).is_err());
        assert!(Policy::new(&[], &["drone.local:80".into()]).is_err());
        let message = Policy::new(&[], &["".into()]).expect_err("refused").to_string();
        assert!(message.starts_with("--allow-host ``: "), "{message}");
    }

    #[test]
    fn the_lists_reach_the_core_rules_with_the_connections_address() {
        let p = Policy::new(&["https://gcs.example:8443/".into()], &["drone.local".into()]).expect("valid");
        let lan: IpAddr = [192, 168, 1, 5].into();
        let rules = p.at(lan, true);
        assert_eq!(
            rules.check("drone.local", Some("https://gcs.example:8443")),
            Ok(())
        );
        assert_eq!(rules.check("192.168.1.5", Some("https://192.168.1.5")), Ok(()));
        assert!(rules.check("192.168.1.6", None).is_err());
        // A socket bound to [::] sees its IPv4 clients arrive on mapped addresses.
        let mapped: IpAddr = "::ffff:192.168.1.5".parse().expect("an address");
        assert_eq!(p.at(mapped, false).check("192.168.1.5:53001", None), Ok(()));
    }
}
