//! Local NED metres to and from global coordinates around a reference
//! point (the vehicle's home), on the WGS-84 ellipsoid.
//!
//! The tangent plane at the reference is used: north and east offsets
//! become latitude and longitude through the ellipsoid's radii of
//! curvature there. Over the few kilometres a multirotor flies, the error
//! is far below GPS accuracy (millimetres at 1 km).

/// WGS-84 semi-major axis, metres.
const A: f64 = 6_378_137.0;
/// WGS-84 first eccentricity squared.
const E2: f64 = 6.694_379_990_14e-3;

/// A global position: degrees and metres above mean sea level.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Global {
    /// Latitude, degrees.
    pub lat: f64,
    /// Longitude, degrees.
    pub lon: f64,
    /// Altitude above mean sea level, metres.
    pub alt: f64,
}

/// The radii of curvature (meridian, prime vertical) at latitude `lat_deg`.
fn radii(lat_deg: f64) -> (f64, f64) {
    let s = lat_deg.to_radians().sin();
    let w = 1.0 - E2 * s * s;
    (A * (1.0 - E2) / (w * w.sqrt()), A / w.sqrt())
}

impl Global {
    /// The point `north`, `east` metres from here and `up` metres higher.
    pub fn offset(self, north: f64, east: f64, up: f64) -> Global {
        let (m, n) = radii(self.lat);
        Global {
            lat: self.lat + (north / m).to_degrees(),
            lon: self.lon + (east / (n * self.lat.to_radians().cos())).to_degrees(),
            alt: self.alt + up,
        }
    }

    /// How far `other` is from here: (north, east, up) metres.
    pub fn ned_to(self, other: Global) -> (f64, f64, f64) {
        let (m, n) = radii(self.lat);
        let north = (other.lat - self.lat).to_radians() * m;
        let east = (other.lon - self.lon).to_radians() * n * self.lat.to_radians().cos();
        (north, east, other.alt - self.alt)
    }

    /// Latitude and longitude as MAVLink's `*_INT` fields: degrees × 1e7.
    pub fn e7(self) -> (i32, i32) {
        let to = |deg: f64| (deg * 1e7).round() as i32;
        (to(self.lat), to(self.lon))
    }

    /// A position from MAVLink's degrees × 1e7 and millimetres.
    pub fn from_e7(lat: i32, lon: i32, alt_mm: i32) -> Global {
        Global {
            lat: f64::from(lat) * 1e-7,
            lon: f64::from(lon) * 1e-7,
            alt: f64::from(alt_mm) * 1e-3,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_kilometre_north_at_the_equator_is_the_meridian_degree_fraction() {
        // One degree of latitude at the equator is 110 574.28 m on WGS-84.
        let p = Global {
            lat: 0.0,
            lon: 0.0,
            alt: 0.0,
        }
        .offset(1000.0, 0.0, 0.0);
        assert!((p.lat - 1000.0 / 110_574.28).abs() < 1e-7, "{}", p.lat);
        assert_eq!(p.lon, 0.0);
    }

    #[test]
    fn a_kilometre_east_shrinks_with_latitude() {
        // One degree of longitude at 60° is 55 800.00 m on WGS-84.
        let p = Global {
            lat: 60.0,
            lon: 10.0,
            alt: 0.0,
        }
        .offset(0.0, 1000.0, 0.0);
        assert!((p.lon - 10.0 - 1000.0 / 55_800.0).abs() < 1e-7, "{}", p.lon);
        assert_eq!(p.lat, 60.0);
    }

    #[test]
    fn offsets_read_back_to_the_millimetre() {
        let home = Global {
            lat: 47.397_742,
            lon: 8.545_594,
            alt: 488.0,
        };
        for (n, e, u) in [(10.0, -5.0, 3.0), (-1500.0, 2200.0, 120.0), (0.001, 0.0, 0.0)] {
            let (n2, e2, u2) = home.ned_to(home.offset(n, e, u));
            assert!((n - n2).abs() < 1e-3 && (e - e2).abs() < 1e-3 && (u - u2).abs() < 1e-9);
        }
    }

    #[test]
    fn mavlink_integer_coordinates_round_to_the_nearest_1e7_degree() {
        let p = Global {
            lat: 47.397_742_04,
            lon: -8.545_594_06,
            alt: 0.0,
        };
        assert_eq!(p.e7(), (473_977_420, -85_455_941));
        assert_eq!(Global::from_e7(473_977_420, -85_455_941, 488_000).alt, 488.0);
    }
}
