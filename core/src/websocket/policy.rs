//! Who may open a session, whatever the request's content: DESIGN.md's
//! "Security defaults", the same on both adapters.
//!
//! - **Origin** (cross-site WebSocket hijacking: any page in the operator's
//!   browser can open a WebSocket to the vehicle): an upgrade without
//!   `Origin` (not a browser), with an `Origin` whose host and port are the
//!   `Host` header's (a page the vehicle serves itself), or with one the
//!   operator allowed (`*` allows any) is accepted; any other gets 403.
//! - **Host** (DNS rebinding: a hostile name that now resolves to the
//!   vehicle makes `Origin` and `Host` agree): the `Host` must name the
//!   address the connection arrived on, a loopback name (`localhost`,
//!   `127.x.y.z`, `[::1]`) when that address is loopback, or a name the
//!   operator allowed; any other gets 403.
//!
//! What an adapter brings is the address the connection arrived on (so a
//! daemon bound to `0.0.0.0` works), whether it is TLS, and its
//! allow-lists. Names compare ASCII case-insensitively; origins compare by
//! scheme, host and port, a missing port being the scheme's default (80
//! for `http` and `ws`, 443 for `https` and `wss`), and a `Host` without a
//! port has the connection's default (443 with TLS, else 80). The port of
//! `Host` is checked to be a number, not compared with the listening port
//! (a rebinding page uses the right one anyway, and a port forwarder may
//! change it).

use core::net::{IpAddr, Ipv4Addr, Ipv6Addr};

use super::handshake::{cut, pieces, same_ignoring_case};

/// Why an upgrade is refused with HTTP 403.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Forbidden {
    /// The `Origin` is neither the server's own nor allowed.
    Origin,
    /// The `Host` names neither the address the connection arrived on nor
    /// an allowed name.
    Host,
}

/// What the policy compares a request with: the adapter's inputs.
#[derive(Clone, Copy, Debug)]
pub struct Policy<'a, S = &'a str> {
    /// The address the connection arrived on (the socket's local address),
    /// an IPv4 one as such: a dual-stack socket shows it IPv4-mapped
    /// (`::ffff:a.b.c.d`), which [`IpAddr::to_canonical`] undoes.
    pub local: IpAddr,
    /// Whether the connection is TLS (`wss://`): the default port of a
    /// `Host` without one.
    pub tls: bool,
    /// Origins accepted besides the same-origin rule (such as
    /// `https://gcs.example:8443`, a trailing `/` allowed), or `*` for any.
    pub allowed_origins: &'a [S],
    /// `Host` names accepted besides the address itself (`drone.local`).
    pub allowed_hosts: &'a [S],
}

impl<S: AsRef<str>> Policy<'_, S> {
    /// Checks an upgrade's `Host` and `Origin` header values.
    pub fn check(&self, host: &str, origin: Option<&str>) -> Result<(), Forbidden> {
        let (name, port) = split_port(host).ok_or(Forbidden::Host)?;
        if !self.host_allowed(name) {
            return Err(Forbidden::Host);
        }
        let Some(origin) = origin else {
            return Ok(());
        };
        let origin = Origin::parse(origin);
        let default_port = if self.tls { 443 } else { 80 };
        let own = origin
            .as_ref()
            .is_some_and(|o| same_ignoring_case(o.host, name) && o.port == port.unwrap_or(default_port));
        let allowed = |entry: &S| {
            let entry = entry.as_ref();
            entry == "*"
                || Origin::parse(entry)
                    .zip(origin.as_ref())
                    .is_some_and(|(a, o)| a.matches(o))
        };
        if own || self.allowed_origins.iter().any(allowed) {
            Ok(())
        } else {
            Err(Forbidden::Origin)
        }
    }

    fn host_allowed(&self, name: &str) -> bool {
        let local = self.local;
        let literal = ip_literal(name);
        literal == Some(local)
            || (local.is_loopback()
                && (same_ignoring_case(name, "localhost") || literal.is_some_and(|ip| ip.is_loopback())))
            || self
                .allowed_hosts
                .iter()
                .any(|h| same_ignoring_case(h.as_ref(), name))
    }
}

/// Whether `text` can be an entry of the allowed origins: `*`, or an
/// origin such as `https://gcs.example:8443` (a trailing `/` allowed).
pub fn valid_origin(text: &str) -> bool {
    text == "*"
        || Origin::parse(text)
            .is_some_and(|o| !o.host.bytes().any(|b| matches!(b, b'/' | b'?' | b'#' | b'@')))
}

/// Whether `text` can be an entry of the allowed host names: a name or
/// address without a port.
pub fn valid_host_name(text: &str) -> bool {
    matches!(split_port(text), Some((_, None)))
}

/// An origin as RFC 6454 serialises it, borrowed: scheme, host, and port
/// (the scheme's default when the text has none).
struct Origin<'a> {
    scheme: &'a str,
    host: &'a str,
    port: u16,
}

impl<'a> Origin<'a> {
    /// The origin in `text`, `scheme://host[:port]` (a trailing `/`
    /// allowed), or `None` for another scheme or a port that is not a
    /// number. What else may follow the host is [`valid_origin`]'s to
    /// refuse: a name holding it never matches a `Host` the policy admits.
    fn parse(text: &'a str) -> Option<Self> {
        let (scheme, rest) = cut(text, b':')?;
        let rest = rest.strip_prefix("//")?;
        let (_, default) = [("http", 80), ("ws", 80), ("https", 443), ("wss", 443)]
            .into_iter()
            .find(|(name, _)| same_ignoring_case(name, scheme))?;
        let authority = match rest.as_bytes().last() {
            Some(b'/') => rest.get(..rest.len() - 1)?,
            _ => rest,
        };
        let (host, port) = split_port(authority)?;
        Some(Origin {
            scheme,
            host,
            port: port.unwrap_or(default),
        })
    }

    fn matches(&self, other: &Origin<'_>) -> bool {
        same_ignoring_case(self.scheme, other.scheme)
            && same_ignoring_case(self.host, other.host)
            && self.port == other.port
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

/// An IP literal as it appears in a `Host`: dotted-quad IPv4, or IPv6
/// in brackets; an IPv4-mapped IPv6 address is taken as its IPv4 address.
fn ip_literal(name: &str) -> Option<IpAddr> {
    match name.strip_prefix('[').and_then(|n| n.strip_suffix(']')) {
        Some(v6) => ipv6(v6).map(|ip| match ip.segments() {
            [0, 0, 0, 0, 0, 0xffff, high, low] => {
                IpAddr::from(Ipv4Addr::from_bits(u32::from(high) << 16 | u32::from(low)))
            }
            _ => IpAddr::V6(ip),
        }),
        None => ipv4(name).map(IpAddr::from),
    }
}

/// Four decimal octets without leading zeros.
fn ipv4(text: &str) -> Option<[u8; 4]> {
    let mut octets = [0u8; 4];
    let mut parts = pieces(text, b'.');
    for octet in &mut octets {
        let part = parts.next()?;
        if part.len() > 1 && part.as_bytes().first() == Some(&b'0') {
            return None;
        }
        *octet = u8::try_from(number(part)?).ok()?;
    }
    parts.next().is_none().then_some(octets)
}

/// IPv6 text (RFC 4291, section 2.2): eight groups of 1 to 4 hex digits,
/// a run of them written `::` once at most. The last two groups written as
/// a dotted quad (`::ffff:1.2.3.4`) are not read: a browser's URL parser
/// writes them in hex in `Host` (`::ffff:102:304`), and their reading cost
/// an MCU 200 bytes of flash. A parser of its own: core's costs 2 KB.
fn ipv6(text: &str) -> Option<Ipv6Addr> {
    let mut head = [0u16; 8];
    match text.as_bytes().windows(2).position(|w| w == b"::") {
        None => (groups(text, &mut head)? == 8).then_some(())?,
        Some(at) => {
            let mut tail = [0u16; 8];
            let before = groups(text.get(..at)?, &mut head)?;
            let after = groups(text.get(at + 2..)?, &mut tail)?;
            if before + after > 7 {
                return None;
            }
            for (group, value) in head.iter_mut().skip(8 - after).zip(tail) {
                *group = value;
            }
        }
    }
    Some(Ipv6Addr::from(head))
}

/// Reads the `:`-separated groups of `text` into `out`; how many there
/// were.
fn groups(text: &str, out: &mut [u16; 8]) -> Option<usize> {
    if text.is_empty() {
        return Some(0);
    }
    let mut n = 0;
    for part in pieces(text, b':') {
        if !(1..=4).contains(&part.len()) {
            return None;
        }
        *out.get_mut(n)? = part
            .chars()
            .try_fold(0u16, |acc, c| Some(acc << 4 | c.to_digit(16)? as u16))?;
        n += 1;
    }
    Some(n)
}

#[cfg(test)]
mod tests {
    extern crate std;

    use std::string::String;

    use proptest::prelude::*;

    use super::*;

    proptest! {
        /// Our parser against std's on text made of IPv6's characters
        /// (without dots: a dotted-quad tail is std's only).
        #[test]
        fn ipv6_text_reads_as_std_reads_it(text in "[0-9a-fA-F:]{0,45}") {
            prop_assert_eq!(ipv6(&text), text.parse::<Ipv6Addr>().ok());
        }

        #[test]
        fn every_address_reads_back_from_its_text(groups in any::<[u16; 8]>()) {
            let ip = Ipv6Addr::from(groups);
            let compressed = std::format!("{ip}");
            if !compressed.contains('.') {
                prop_assert_eq!(ipv6(&compressed), Some(ip));
            }
            let full: String = groups.iter().map(|g| std::format!("{g:X}:")).collect();
            prop_assert_eq!(ipv6(full.trim_end_matches(':')), Some(ip));
        }
    }

    #[test]
    fn a_dotted_quad_tail_is_not_read() {
        assert_eq!(ipv6("::ffff:1.2.3.4"), None);
        assert_eq!(ipv6("::ffff:102:304"), "::ffff:1.2.3.4".parse().ok());
    }
}
