//! The flight envelope (DESIGN.md, "Flight authority"): where a vehicle
//! may be sent, checked for every command that gives it a target —
//! `takeoff`, `set_sp_ned`, `zyhk` heights, mission waypoints (at upload
//! and again at `mw_exec`), the RTL climb — by every vehicle alike.
//!
//! Altitude above home is at least `min_alt` and at most `max_alt`; the
//! horizontal distance from home at most `geofence_radius`. Takeoff and
//! return altitudes are not refused for the limits: they are clipped into
//! them, and the answers say what the vehicle will fly.

use std::fmt;

use super::Ned;

/// A vehicle's limits around its home.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Envelope {
    /// Home: where the last takeoff started.
    pub(crate) home: Ned,
    /// Lowest target altitude above home, m.
    pub(crate) min_alt: f64,
    /// Highest target altitude above home, m.
    pub(crate) max_alt: f64,
    /// Largest horizontal distance from home, m.
    pub(crate) radius: f64,
}

/// Why a target is outside the envelope: DESIGN.md's `<what> <value>
/// <above|below|beyond> <limit name> <limit>`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Outside {
    /// Lower than `min_alt`.
    Below {
        /// The target's altitude above home, m.
        alt: f64,
        /// `min_alt`.
        min: f64,
    },
    /// Higher than `max_alt`.
    Above {
        /// The target's altitude above home, m.
        alt: f64,
        /// `max_alt`.
        max: f64,
    },
    /// Farther from home than `geofence_radius`.
    Beyond {
        /// The target's horizontal distance from home, m.
        dist: f64,
        /// `geofence_radius`.
        radius: f64,
    },
}

impl fmt::Display for Outside {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Outside::Below { alt, min } => {
                write!(f, "altitude {} m below min_alt {} m", short(alt), short(min))
            }
            Outside::Above { alt, max } => {
                write!(f, "altitude {} m above max_alt {} m", short(alt), short(max))
            }
            Outside::Beyond { dist, radius } => write!(
                f,
                "distance from home {} m beyond geofence_radius {} m",
                short(dist),
                short(radius)
            ),
        }
    }
}

/// A number as a client would write it: the `f32` it is on the wire (so
/// that `4` stays `4` and `0.1` `0.1`), with an exponent when that is
/// shorter than 16 characters of digits (`1e300`).
fn short(v: f64) -> String {
    let single = v as f32;
    let text = if single.is_finite() {
        single.to_string()
    } else {
        v.to_string()
    };
    if text.len() <= 16 { text } else { format!("{v:e}") }
}

impl Envelope {
    /// No limits at all (a mission read only to be listed).
    pub(crate) const NONE: Envelope = Envelope {
        home: Ned {
            x: 0.0,
            y: 0.0,
            z: 0.0,
        },
        min_alt: f64::NEG_INFINITY,
        max_alt: f64::INFINITY,
        radius: f64::INFINITY,
    };

    /// `p`'s altitude above home, m (never `-0`).
    fn altitude(&self, p: Ned) -> f64 {
        (self.home.z - p.z) + 0.0
    }

    /// Whether the vehicle may be sent to `p`; why not, if not.
    pub(crate) fn check(&self, p: Ned) -> Result<(), Outside> {
        self.check_horizontal(p)?;
        self.check_altitude(self.altitude(p))
    }

    /// Whether `p` is within `geofence_radius` of home.
    pub(crate) fn check_horizontal(&self, p: Ned) -> Result<(), Outside> {
        let dist = (p.x - self.home.x).hypot(p.y - self.home.y);
        if dist > self.radius {
            return Err(Outside::Beyond {
                dist: round_up(dist),
                radius: self.radius,
            });
        }
        Ok(())
    }

    /// Whether an altitude above home is within `min_alt..=max_alt`.
    pub(crate) fn check_altitude(&self, alt: f64) -> Result<(), Outside> {
        if alt < self.min_alt || alt.is_nan() {
            Err(Outside::Below {
                alt,
                min: self.min_alt,
            })
        } else if alt > self.max_alt {
            Err(Outside::Above {
                alt,
                max: self.max_alt,
            })
        } else {
            Ok(())
        }
    }

    /// The altitude a takeoff or a return to `wanted` (`takeoff_alt`,
    /// `rtl_alt`) climbs to: `wanted` clipped into `min_alt..=max_alt`.
    pub(crate) fn clip(&self, wanted: f64) -> f64 {
        wanted.min(self.max_alt).max(self.min_alt)
    }
}

/// A distance for a reason, one decimal, rounded away from the limit so
/// that `500.04 m beyond 500 m` never reads `500 m beyond 500 m`. Rounded
/// from the number as a client wrote it (the `f32` it sent, read back as
/// its shortest decimal): `10.1` stays `10.1`, though as an `f32` it is
/// 10.100000381.
fn round_up(dist: f64) -> f64 {
    if dist >= 1e6 {
        return dist;
    }
    let sent: f64 = (dist as f32).to_string().parse().unwrap_or(dist);
    (sent * 10.0 - 1e-9).ceil() / 10.0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn envelope() -> Envelope {
        Envelope {
            home: Ned::default(),
            min_alt: 0.5,
            max_alt: 3.0,
            radius: 100.0,
        }
    }

    #[test]
    fn inside_and_on_each_limit_is_flyable() {
        let e = envelope();
        for p in [
            Ned::new(0.0, 0.0, -0.5),
            Ned::new(0.0, 0.0, -3.0),
            Ned::new(100.0, 0.0, -1.0),
            Ned::new(60.0, 80.0, -2.0),
        ] {
            assert_eq!(e.check(p), Ok(()), "{p:?}");
        }
    }

    #[test]
    fn just_outside_each_limit_says_which_in_the_protocols_words() {
        let e = envelope();
        let why = |p| e.check(p).unwrap_err().to_string();
        assert_eq!(why(Ned::new(0.0, 0.0, -4.0)), "altitude 4 m above max_alt 3 m");
        assert_eq!(
            why(Ned::new(0.0, 0.0, -0.3)),
            "altitude 0.3 m below min_alt 0.5 m"
        );
        assert_eq!(why(Ned::new(0.0, 0.0, 0.0)), "altitude 0 m below min_alt 0.5 m");
        assert_eq!(
            why(Ned::new(0.0, 0.0, -1e-50)),
            "altitude 0 m below min_alt 0.5 m"
        );
        assert_eq!(
            why(Ned::new(100.01, 0.0, -1.0)),
            "distance from home 100.1 m beyond geofence_radius 100 m"
        );
        assert_eq!(
            why(Ned::new(f64::from(100.1f32), 0.0, -1.0)),
            "distance from home 100.1 m beyond geofence_radius 100 m"
        );
        assert_eq!(
            why(Ned::new(1e300, 0.0, -1.0)),
            "distance from home 1e300 m beyond geofence_radius 100 m"
        );
    }

    #[test]
    fn takeoff_and_return_altitudes_are_clipped_not_refused() {
        let e = envelope();
        assert_eq!(e.clip(5.0), 3.0);
        assert_eq!(e.clip(0.2), 0.5);
        assert_eq!(e.clip(2.0), 2.0);
    }
}
