//! Who may open a session: the `Origin` and `Host` rules of DESIGN.md,
//! "Security defaults".
//!
//! A browser sends `Origin` with every WebSocket upgrade, so any page the
//! operator has open could otherwise drive the vehicle (cross-site
//! WebSocket hijacking). An upgrade is accepted when it has no `Origin`
//! (not a browser), when its `Origin` names the host and port of its own
//! `Host` header (a page served by the vehicle), or when the operator
//! allowed that origin. DNS rebinding makes a hostile page's `Origin` and
//! `Host` agree, so `Host` must also name the address the connection
//! arrived on, a loopback name when that address is loopback, or a name the
//! operator allowed.

use std::fmt;
use std::net::IpAddr;

/// Why an upgrade is refused with HTTP 403.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Forbidden {
    /// The `Origin` is neither the server's own nor allowed.
    Origin,
    /// The `Host` names neither this server's address nor an allowed name.
    Host,
}

impl fmt::Display for Forbidden {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Forbidden::Origin => "this Origin may not open sessions (lluavd --allow-origin)",
            Forbidden::Host => "this Host name is not served here (lluavd --allow-host)",
        })
    }
}

/// A value of `--allow-origin` or `--allow-host` that cannot be used.
#[derive(Debug, thiserror::Error)]
#[error("{what} `{value}`: {why}")]
pub struct PolicyError {
    what: &'static str,
    value: String,
    why: &'static str,
}

/// An origin as RFC 6454 serialises it: scheme, host, port (the scheme's
/// default when the text has none). Hosts are compared case-insensitively.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Origin {
    scheme: String,
    host: String,
    port: u16,
}

impl Origin {
    fn parse(text: &str) -> Option<Origin> {
        let (scheme, rest) = text.split_once("://")?;
        let scheme = scheme.to_ascii_lowercase();
        let default_port = match scheme.as_str() {
            "http" | "ws" => 80,
            "https" | "wss" => 443,
            _ => return None,
        };
        // A serialised origin has no path; a URL given on the command line
        // may end with a slash.
        let authority = rest.strip_suffix('/').unwrap_or(rest);
        if authority.contains(['/', '?', '#', '@']) {
            return None;
        }
        let (host, port) = split_host_port(authority)?;
        Some(Origin {
            scheme,
            host,
            port: port.unwrap_or(default_port),
        })
    }

    /// The origin as `--allow-origin` takes it, without a default port.
    fn text(&self) -> String {
        let default_port = if matches!(self.scheme.as_str(), "https" | "wss") {
            443
        } else {
            80
        };
        if self.port == default_port {
            format!("{}://{}", self.scheme, self.host)
        } else {
            format!("{}://{}:{}", self.scheme, self.host, self.port)
        }
    }
}

/// Splits `host[:port]` (`[v6]:port` for IPv6) and lowercases the host.
fn split_host_port(authority: &str) -> Option<(String, Option<u16>)> {
    let (host, port) = if let Some(rest) = authority.strip_prefix('[') {
        let (v6, after) = rest.split_once(']')?;
        v6.parse::<std::net::Ipv6Addr>().ok()?;
        match after {
            "" => (format!("[{v6}]"), None),
            _ => (format!("[{v6}]"), Some(after.strip_prefix(':')?)),
        }
    } else {
        match authority.rsplit_once(':') {
            Some((h, p)) => (h.to_owned(), Some(p)),
            None => (authority.to_owned(), None),
        }
    };
    let valid = |c: char| c.is_ascii_alphanumeric() || matches!(c, '-' | '.' | '_' | '[' | ']' | ':');
    if host.is_empty() || !host.chars().all(valid) {
        return None;
    }
    let port = match port {
        Some(p) => Some(p.parse::<u16>().ok()?),
        None => None,
    };
    Some((host.to_ascii_lowercase(), port))
}

/// The host part of a host name or address as written in `Host`, as an
/// address if it is one (`[::1]` and `127.0.0.1` are, `localhost` is not).
fn host_ip(host: &str) -> Option<IpAddr> {
    let bare = host
        .strip_prefix('[')
        .and_then(|h| h.strip_suffix(']'))
        .unwrap_or(host);
    bare.parse::<IpAddr>().ok().map(|ip| ip.to_canonical())
}

/// The operator's allow-lists, checked against every upgrade.
#[derive(Clone, Debug, Default)]
pub struct Policy {
    any_origin: bool,
    origins: Vec<Origin>,
    hosts: Vec<String>,
}

impl Policy {
    /// A policy allowing `origins` (URLs such as `https://gcs.example:8443`,
    /// or `*` for any) and the extra `Host` names `hosts` (`drone.local`).
    pub fn new(origins: &[String], hosts: &[String]) -> Result<Policy, PolicyError> {
        let mut policy = Policy::default();
        for text in origins {
            if text == "*" {
                policy.any_origin = true;
                continue;
            }
            let origin = Origin::parse(text).ok_or_else(|| PolicyError {
                what: "--allow-origin",
                value: text.clone(),
                why: "not an origin such as https://gcs.example:8443 (or * for any)",
            })?;
            policy.origins.push(origin);
        }
        for text in hosts {
            match split_host_port(text) {
                Some((host, None)) => policy.hosts.push(host),
                _ => {
                    return Err(PolicyError {
                        what: "--allow-host",
                        value: text.clone(),
                        why: "not a host name such as drone.local (without a port)",
                    });
                }
            }
        }
        Ok(policy)
    }

    /// The allowed origins as `--allow-origin` takes them (`*` for any).
    pub fn origins(&self) -> Vec<String> {
        let any = self.any_origin.then(|| "*".to_owned());
        any.into_iter()
            .chain(self.origins.iter().map(Origin::text))
            .collect()
    }

    /// The extra host names allowed in `Host`.
    pub fn hosts(&self) -> Vec<String> {
        self.hosts.clone()
    }

    /// Checks an upgrade's `Host` and `Origin` headers; `local` is the
    /// address the connection arrived on and `tls` whether it is `wss://`
    /// (for the default port of a `Host` without one).
    pub fn check(&self, host: &str, origin: Option<&str>, local: IpAddr, tls: bool) -> Result<(), Forbidden> {
        let (host_name, host_port) = split_host_port(host.trim()).ok_or(Forbidden::Host)?;
        if !self.host_allowed(&host_name, local) {
            return Err(Forbidden::Host);
        }
        let Some(origin) = origin else {
            return Ok(());
        };
        if self.any_origin {
            return Ok(());
        }
        let origin = Origin::parse(origin.trim()).ok_or(Forbidden::Origin)?;
        let port = host_port.unwrap_or(if tls { 443 } else { 80 });
        if (origin.host == host_name && origin.port == port) || self.origins.contains(&origin) {
            Ok(())
        } else {
            Err(Forbidden::Origin)
        }
    }

    fn host_allowed(&self, host: &str, local: IpAddr) -> bool {
        let local = local.to_canonical();
        match host_ip(host) {
            Some(ip) => ip == local || (local.is_loopback() && ip.is_loopback()),
            None => (local.is_loopback() && host == "localhost") || self.hosts.iter().any(|h| h == host),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LOOPBACK: IpAddr = IpAddr::V4(std::net::Ipv4Addr::LOCALHOST);
    const LAN: IpAddr = IpAddr::V4(std::net::Ipv4Addr::new(192, 168, 1, 5));

    fn policy(origins: &[&str], hosts: &[&str]) -> Policy {
        let own = |v: &[&str]| v.iter().map(|s| (*s).to_owned()).collect::<Vec<_>>();
        Policy::new(&own(origins), &own(hosts)).expect("valid policy")
    }

    #[test]
    fn no_origin_is_a_non_browser_client_and_accepted() {
        assert_eq!(
            policy(&[], &[]).check("127.0.0.1:53001", None, LOOPBACK, false),
            Ok(())
        );
    }

    #[test]
    fn a_page_served_by_the_vehicle_itself_is_accepted() {
        let p = policy(&[], &[]);
        assert_eq!(
            p.check("192.168.1.5:53001", Some("http://192.168.1.5:53001"), LAN, false),
            Ok(())
        );
        assert_eq!(
            p.check("LOCALHOST:8080", Some("http://localhost:8080"), LOOPBACK, false),
            Ok(())
        );
        assert_eq!(
            p.check(
                "[::1]:1",
                Some("http://[::1]:1"),
                "::1".parse().expect("ip"),
                false
            ),
            Ok(())
        );
        // Default ports on both sides.
        assert_eq!(
            p.check("192.168.1.5", Some("https://192.168.1.5"), LAN, true),
            Ok(())
        );
    }

    #[test]
    fn a_foreign_origin_is_refused_unless_allowed() {
        let host = "127.0.0.1:53001";
        let evil = Some("https://evil.example");
        assert_eq!(
            policy(&[], &[]).check(host, evil, LOOPBACK, false),
            Err(Forbidden::Origin)
        );
        assert_eq!(
            policy(&["https://evil.example/"], &[]).check(host, evil, LOOPBACK, false),
            Ok(())
        );
        assert_eq!(policy(&["*"], &[]).check(host, evil, LOOPBACK, false), Ok(()));
        assert_eq!(
            policy(&[], &[]).check(host, Some("null"), LOOPBACK, false),
            Err(Forbidden::Origin)
        );
        // Same host, another port: another origin.
        let other_port = Some("http://127.0.0.1:8000");
        assert_eq!(
            policy(&[], &[]).check(host, other_port, LOOPBACK, false),
            Err(Forbidden::Origin)
        );
    }

    #[test]
    fn a_rebound_host_name_is_refused_even_with_a_matching_origin() {
        let p = policy(&[], &[]);
        let origin = Some("http://evil.example:53001");
        assert_eq!(
            p.check("evil.example:53001", origin, LOOPBACK, false),
            Err(Forbidden::Host)
        );
        assert_eq!(
            p.check("evil.example:53001", None, LOOPBACK, false),
            Err(Forbidden::Host)
        );
        let allowed = policy(&[], &["Drone.local"]);
        assert_eq!(
            allowed.check("drone.local:53001", Some("http://drone.local:53001"), LAN, false),
            Ok(())
        );
    }

    #[test]
    fn host_must_name_the_local_address() {
        let p = policy(&[], &[]);
        assert_eq!(
            p.check("192.168.1.6:53001", None, LAN, false),
            Err(Forbidden::Host)
        );
        assert_eq!(p.check("localhost:53001", None, LAN, false), Err(Forbidden::Host));
        assert_eq!(p.check("127.0.0.1:53001", None, LAN, false), Err(Forbidden::Host));
        assert_eq!(p.check("127.0.0.2:53001", None, LOOPBACK, false), Ok(()));
        let mapped: IpAddr = "::ffff:192.168.1.5".parse().expect("ip");
        assert_eq!(p.check("192.168.1.5:53001", None, mapped, false), Ok(()));
        assert_eq!(p.check("", None, LOOPBACK, false), Err(Forbidden::Host));
        assert_eq!(p.check("a b", None, LOOPBACK, false), Err(Forbidden::Host));
    }

    #[test]
    fn unusable_allow_list_entries_are_refused() {
        assert!(Policy::new(&["evil.example".into()], &[]).is_err());
        assert!(Policy::new(&["ftp://x".into()], &[]).is_err());
        assert!(Policy::new(&["http://x/path".into()], &[]).is_err());
        assert!(Policy::new(&[], &["drone.local:80".into()]).is_err());
    }
}
