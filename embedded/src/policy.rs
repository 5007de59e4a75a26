//! Which upgrade requests may open a session, whatever their content:
//! DESIGN.md's "Security defaults", without allocating.
//!
//! - **Origin** (cross-site WebSocket hijacking: any page in the operator's
//!   browser can open a WebSocket to the vehicle): a request without
//!   `Origin` (not a browser), with an `Origin` whose host and port are the
//!   `Host` header's (a page the vehicle serves itself), or with one in the
//!   allow-list (`*` allows any) is accepted; any other gets 403.
//! - **Host** (DNS rebinding: a hostile name that now resolves to the
//!   vehicle makes `Origin` and `Host` agree): the `Host` must name the
//!   address the connection arrived at (with or without a port), a loopback
//!   name (`localhost`, `127.x.y.z`, `[::1]`) when that address is loopback,
//!   or a name in the allow-list; any other gets 403.
//!
//! Names compare ASCII case-insensitively. Ports in `Host` are not
//! compared with the listening port (a rebinding page uses the right one
//! anyway, and a port forwarder may change it), only checked to be numbers.
//! An `Origin` without a port has its scheme's default (80 for `http` and
//! `ws`, 443 for `https` and `wss`), and so has a `Host` without one (80:
//! this adapter speaks plain `ws`).

use core::net::{IpAddr, Ipv4Addr, Ipv6Addr};

use crate::handshake::{Rejection, Request, cut, pieces};

/// What the policy compares a request with.
#[derive(Clone, Copy, Debug)]
pub struct Policy<'a> {
    /// The address the connection arrived at (the socket's local address).
    pub address: IpAddr,
    /// `Origin` values accepted besides the same-origin rule (exact
    /// serialized origins such as `http://192.168.1.20:8080`, or `*`).
    pub allowed_origins: &'a [&'a str],
    /// `Host` names accepted besides the address itself.
    pub allowed_hosts: &'a [&'a str],
}

impl Policy<'_> {
    /// Whether `request` may open a session.
    pub fn check(&self, request: &Request<'_>) -> Result<(), Rejection> {
        let (name, _) = split_port(request.host).ok_or(Rejection::ForeignHost)?;
        if !self.host_allowed(name) {
            return Err(Rejection::ForeignHost);
        }
        match request.origin {
            None => Ok(()),
            Some(origin) if self.origin_allowed(origin, request.host) => Ok(()),
            Some(_) => Err(Rejection::ForeignOrigin),
        }
    }

    fn host_allowed(&self, name: &str) -> bool {
        let literal = parse_ip(name);
        literal == Some(self.address)
            || (self.address.is_loopback()
                && (name.eq_ignore_ascii_case("localhost") || literal.is_some_and(|ip| ip.is_loopback())))
            || self.allowed_hosts.iter().any(|h| h.eq_ignore_ascii_case(name))
    }

    fn origin_allowed(&self, origin: &str, host: &str) -> bool {
        if self
            .allowed_origins
            .iter()
            .any(|o| *o == "*" || o.eq_ignore_ascii_case(origin))
        {
            return true;
        }
        let Some((scheme, authority)) =
            cut(origin, b':').and_then(|(s, rest)| Some((s, rest.strip_prefix("//")?)))
        else {
            return false;
        };
        let is = |names: [&str; 2]| names.iter().any(|n| n.eq_ignore_ascii_case(scheme));
        let default = if is(["http", "ws"]) {
            80
        } else if is(["https", "wss"]) {
            443
        } else {
            return false;
        };
        match (split_port(authority), split_port(host)) {
            (Some((origin_name, origin_port)), Some((host_name, host_port))) => {
                origin_name.eq_ignore_ascii_case(host_name)
                    && origin_port.unwrap_or(default) == host_port.unwrap_or(80)
            }
            _ => false,
        }
    }
}

/// `name[:port]` or `[v6][:port]`: the name (brackets kept) and the port,
/// or `None` when the port is not a number or the name is empty.
fn split_port(authority: &str) -> Option<(&str, Option<u16>)> {
    // An IPv6 literal's colons are inside its brackets.
    let bytes = authority.as_bytes();
    let after = match bytes.iter().position(|&b| b == b']') {
        Some(end) if bytes.first() == Some(&b'[') => end + 1,
        _ => 0,
    };
    let (name, port) = match bytes.get(after..)?.iter().position(|&b| b == b':') {
        Some(colon) => {
            let (name, rest) = authority.split_at_checked(after + colon)?;
            (name, Some(number(rest.get(1..)?)?))
        }
        None => (authority, None),
    };
    if after > 0 && name.len() != after {
        return None;
    }
    (!name.is_empty()).then_some((name, port))
}

/// A decimal number of 1 to 5 digits that fits a `u16`.
fn number(digits: &str) -> Option<u16> {
    if digits.is_empty() || digits.len() > 5 {
        return None;
    }
    let value = digits.bytes().try_fold(0u32, |acc, b| {
        b.is_ascii_digit().then(|| acc * 10 + u32::from(b - b'0'))
    })?;
    u16::try_from(value).ok()
}

/// An IP literal as it appears in a `Host`: dotted-quad IPv4 (no leading
/// zeros), or the IPv6 loopback `[::1]` (the adapter speaks IPv4 only, so
/// no other IPv6 address can be its own).
fn parse_ip(name: &str) -> Option<IpAddr> {
    if name == "[::1]" {
        return Some(IpAddr::V6(Ipv6Addr::LOCALHOST));
    }
    let mut octets = [0u8; 4];
    let mut parts = pieces(name, b'.');
    for octet in &mut octets {
        let part = parts.next()?;
        if part.len() > 1 && part.as_bytes().first() == Some(&b'0') {
            return None;
        }
        *octet = u8::try_from(number(part)?).ok()?;
    }
    match parts.next() {
        None => Some(IpAddr::V4(Ipv4Addr::from(octets))),
        Some(_) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const KEY: &[u8; 24] = b"dGhlIHNhbXBsZSBub25jZQ==";

    fn policy(address: [u8; 4]) -> Policy<'static> {
        Policy {
            address: IpAddr::V4(address.into()),
            allowed_origins: &[],
            allowed_hosts: &[],
        }
    }

    fn request<'a>(host: &'a str, origin: Option<&'a str>) -> Request<'a> {
        Request {
            key: KEY,
            host,
            origin,
        }
    }

    #[test]
    fn host_must_name_the_address_with_or_without_a_port() {
        let p = policy([192, 168, 1, 53]);
        assert_eq!(p.check(&request("192.168.1.53", None)), Ok(()));
        assert_eq!(p.check(&request("192.168.1.53:53001", None)), Ok(()));
        assert_eq!(
            p.check(&request("192.168.1.54:53001", None)),
            Err(Rejection::ForeignHost)
        );
        assert_eq!(
            p.check(&request("evil.example:53001", None)),
            Err(Rejection::ForeignHost)
        );
        assert_eq!(
            p.check(&request("localhost:53001", None)),
            Err(Rejection::ForeignHost)
        );
        assert_eq!(
            p.check(&request("192.168.1.53:x", None)),
            Err(Rejection::ForeignHost)
        );
        assert_eq!(
            p.check(&request("192.168.1.53:99999", None)),
            Err(Rejection::ForeignHost)
        );
    }

    #[test]
    fn loopback_names_pass_only_when_bound_to_loopback() {
        let p = policy([127, 0, 0, 1]);
        for host in [
            "localhost",
            "LOCALHOST:53001",
            "127.0.0.1",
            "127.53.0.1:53001",
            "[::1]:53001",
        ] {
            assert_eq!(p.check(&request(host, None)), Ok(()), "{host}");
        }
        assert_eq!(
            p.check(&request("evil.example", None)),
            Err(Rejection::ForeignHost)
        );
    }

    #[test]
    fn ip_literals_are_read_strictly() {
        assert_eq!(parse_ip("10.0.0.2"), Some(IpAddr::V4(Ipv4Addr::new(10, 0, 0, 2))));
        for bad in [
            "10.0.0",
            "10.0.0.2.1",
            "10.0.0.256",
            "10.0.0.02",
            "10.0.0.+2",
            "10..0.2",
            "",
        ] {
            assert_eq!(parse_ip(bad), None, "{bad}");
        }
        assert_eq!(split_port("[::1]:53001"), Some(("[::1]", Some(53001))));
        assert_eq!(split_port("[::1]"), Some(("[::1]", None)));
        assert_eq!(split_port("[::1]x"), None);
        assert_eq!(split_port("host:"), None);
        assert_eq!(split_port(":80"), None);
        assert_eq!(split_port("host:65536"), None);
    }

    #[test]
    fn allowed_host_names_pass() {
        let p = Policy {
            allowed_hosts: &["drone.local"],
            ..policy([10, 0, 0, 2])
        };
        assert_eq!(p.check(&request("Drone.Local:53001", None)), Ok(()));
        assert_eq!(
            p.check(&request("other.local:53001", None)),
            Err(Rejection::ForeignHost)
        );
    }

    #[test]
    fn origin_must_be_the_hosts_own_or_allowed() {
        let p = policy([10, 0, 0, 2]);
        let own = request("10.0.0.2:53001", Some("http://10.0.0.2:53001"));
        assert_eq!(p.check(&own), Ok(()));
        let foreign = request("10.0.0.2:53001", Some("https://evil.example"));
        assert_eq!(p.check(&foreign), Err(Rejection::ForeignOrigin));
        let other_port = request("10.0.0.2:53001", Some("http://10.0.0.2:8080"));
        assert_eq!(p.check(&other_port), Err(Rejection::ForeignOrigin));
        let null = request("10.0.0.2:53001", Some("null"));
        assert_eq!(p.check(&null), Err(Rejection::ForeignOrigin));
    }

    #[test]
    fn default_ports_make_origin_and_host_agree() {
        let p = policy([10, 0, 0, 2]);
        assert_eq!(p.check(&request("10.0.0.2", Some("http://10.0.0.2"))), Ok(()));
        assert_eq!(p.check(&request("10.0.0.2:80", Some("HTTP://10.0.0.2"))), Ok(()));
        assert_eq!(
            p.check(&request("10.0.0.2", Some("https://10.0.0.2"))),
            Err(Rejection::ForeignOrigin)
        );
    }

    #[test]
    fn allow_list_admits_named_origins_or_any() {
        let named = Policy {
            allowed_origins: &["http://gcs.local:8080"],
            ..policy([10, 0, 0, 2])
        };
        assert_eq!(
            named.check(&request("10.0.0.2", Some("http://gcs.local:8080"))),
            Ok(())
        );
        assert_eq!(
            named.check(&request("10.0.0.2", Some("http://gcs.local:8081"))),
            Err(Rejection::ForeignOrigin)
        );
        let any = Policy {
            allowed_origins: &["*"],
            ..policy([10, 0, 0, 2])
        };
        assert_eq!(
            any.check(&request("10.0.0.2", Some("https://evil.example"))),
            Ok(())
        );
        // The allow-list of origins never excuses a foreign Host.
        assert_eq!(
            any.check(&request("evil.example", Some("https://evil.example"))),
            Err(Rejection::ForeignHost)
        );
    }
}
