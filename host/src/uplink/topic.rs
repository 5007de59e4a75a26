//! The topic layout (DESIGN.md, "Uplink"): `lluav/V/status`, `lluav/V/state`,
//! `lluav/V/events`, `lluav/V/req/C` and `lluav/V/res/C`, with `V` a vehicle id and `C` an
//! operator's client id, both 1-64 of `[A-Za-z0-9_-]`.

/// Longest vehicle or client id.
pub const MAX_NAME: usize = 64;

/// The first level of every topic.
pub const ROOT: &str = "lluav";

/// Whether `name` can be a vehicle or client id: 1-64 of `[A-Za-z0-9_-]`.
/// Nothing else can go into a topic level safely: `+`, `#` and `/` are MQTT
/// syntax, and a name is also a log field and a table key.
pub fn valid_name(name: &str) -> bool {
    (1..=MAX_NAME).contains(&name.len())
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
}

/// `name` made valid: characters outside the alphabet become `-`, cut to
/// 64; `fallback` when nothing is left.
pub fn sanitize(name: &str, fallback: &str) -> String {
    let clean: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                c
            } else {
                '-'
            }
        })
        .take(MAX_NAME)
        .collect();
    if clean.is_empty() {
        fallback.to_owned()
    } else {
        clean
    }
}

/// One vehicle's topics.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Topics {
    vehicle: String,
    status: String,
    state: String,
    events: String,
    requests: String,
}

/// Why a message on the request filter is not a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Stray {
    /// The topic is not `lluav/V/req/C` for this vehicle.
    Layout,
    /// `C` is not 1-64 of `[A-Za-z0-9_-]`.
    ClientId,
    /// A retained message: it would run whenever the vehicle subscribes,
    /// long after it was sent.
    Retained,
}

impl std::fmt::Display for Stray {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Stray::Layout => "a message on a topic outside lluav/V/req/C; ignored",
            Stray::ClientId => "a request whose client id is not 1-64 of [A-Za-z0-9_-]; ignored",
            Stray::Retained => "a retained request (it would run late); ignored",
        })
    }
}

impl Topics {
    /// The topics of vehicle `vehicle` (a valid name).
    pub fn new(vehicle: &str) -> Topics {
        Topics {
            vehicle: vehicle.to_owned(),
            status: format!("{ROOT}/{vehicle}/status"),
            state: format!("{ROOT}/{vehicle}/state"),
            events: format!("{ROOT}/{vehicle}/events"),
            requests: format!("{ROOT}/{vehicle}/req/"),
        }
    }

    /// The vehicle id.
    pub fn vehicle(&self) -> &str {
        &self.vehicle
    }

    /// `lluav/V/status`.
    pub fn status(&self) -> &str {
        &self.status
    }

    /// `lluav/V/state`.
    pub fn state(&self) -> &str {
        &self.state
    }

    /// `lluav/V/events`.
    pub fn events(&self) -> &str {
        &self.events
    }

    /// `lluav/V/req/+`: what the vehicle subscribes to.
    pub fn request_filter(&self) -> String {
        format!("{}+", self.requests)
    }

    /// `lluav/V/req/C`: where client `client` sends its requests.
    pub fn request(&self, client: &str) -> String {
        format!("{}{client}", self.requests)
    }

    /// `lluav/V/res/C`: where client `client` gets its responses.
    pub fn response(&self, client: &str) -> String {
        format!("{ROOT}/{}/res/{client}", self.vehicle)
    }

    /// The client id of a request on `topic`.
    pub fn client_of<'t>(&self, topic: &'t str) -> Result<&'t str, Stray> {
        let client = topic.strip_prefix(self.requests.as_str()).ok_or(Stray::Layout)?;
        if valid_name(client) {
            Ok(client)
        } else {
            Err(Stray::ClientId)
        }
    }
}

/// What an operator subscribes to: every vehicle's `kind` topic
/// (`status`, `state`), or `res/C` for its own responses.
pub fn every_vehicle(kind: &str) -> String {
    format!("{ROOT}/+/{kind}")
}

/// The vehicle id and the rest of `topic`, if it is under `lluav/V/`.
pub fn split_vehicle(topic: &str) -> Option<(&str, &str)> {
    let rest = topic.strip_prefix(ROOT)?.strip_prefix('/')?;
    let (vehicle, kind) = rest.split_once('/')?;
    valid_name(vehicle).then_some((vehicle, kind))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_1_to_64_of_the_alphabet() {
        assert!(valid_name("drone-7_A"));
        assert!(valid_name(&"a".repeat(64)));
        assert!(!valid_name(&"a".repeat(65)));
        for bad in ["", "a/b", "a+", "#", "é", "a b", "a.b"] {
            assert!(!valid_name(bad), "{bad:?}");
        }
    }

    #[test]
    fn host_names_become_vehicle_ids() {
        assert_eq!(sanitize("drone.local", "x"), "drone-local");
        assert_eq!(sanitize("", "vehicle"), "vehicle");
        assert_eq!(sanitize(&"é".repeat(80), "x"), "-".repeat(64));
    }

    #[test]
    fn requests_are_read_only_under_the_vehicles_own_prefix() {
        let t = Topics::new("v1");
        assert_eq!(t.client_of("lluav/v1/req/op-1"), Ok("op-1"));
        assert_eq!(t.client_of("lluav/v2/req/op-1"), Err(Stray::Layout));
        assert_eq!(t.client_of("lluav/v1/req/a/b"), Err(Stray::ClientId));
        assert_eq!(t.client_of("lluav/v1/req/"), Err(Stray::ClientId));
        assert_eq!(t.response("op-1"), "lluav/v1/res/op-1");
        assert_eq!(t.request_filter(), "lluav/v1/req/+");
        assert_eq!(t.events(), "lluav/v1/events");
        assert_eq!(split_vehicle("lluav/v1/res/op"), Some(("v1", "res/op")));
        assert_eq!(split_vehicle("other/v1/state"), None);
    }
}
