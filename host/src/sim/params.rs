//! The autopilot's parameters: typed, with defaults and ranges, persisted
//! atomically.
//!
//! `set_param` and `reset_param` change the working values, which take
//! effect at once; `save_param 1` writes them to `params.json` in the data
//! directory (temp file, fsync, rename, fsync of the directory).
//! `save_param 0` saves nothing and changes nothing: the working values stay
//! in effect until a restart, and the answer names the parameters whose
//! working value is not saved. [`Params::load`] reads the file.

use std::io;
use std::path::{Path, PathBuf};

use lluav_core::number::{format_f32, parse_f32};
use lluav_core::{Args, Command, CommandId, Fields, Number};

use super::error::{SimError, SimResult};
use crate::files::atomic_write;

/// File in the data directory holding the saved parameters.
pub(crate) const PARAMS_FILE: &str = "params.json";

/// A parameter value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Value {
    /// An integer.
    Int(i64),
    /// A real number: an `f32`, as the protocol carries it (MAVLink's
    /// parameters are too).
    Float(f32),
    /// A boolean (`0`/`1`/`true`/`false` on the wire).
    Bool(bool),
}

impl Value {
    /// The type's name, as `get_param` reports it.
    pub(crate) fn type_name(self) -> &'static str {
        match self {
            Value::Int(_) => "int",
            Value::Float(_) => "float",
            Value::Bool(_) => "bool",
        }
    }

    /// The value as the simulator computes with it: a float is the `f64`
    /// of the decimal it is written as (0.7, not 0.699999988079071).
    fn as_f64(self) -> f64 {
        match self {
            Value::Int(i) => i as f64,
            Value::Float(f) => format_f32(f).as_str().parse().unwrap_or(f64::from(f)),
            Value::Bool(b) => f64::from(u8::from(b)),
        }
    }

    /// Parses `text` as a value of the same type as `self`, in the
    /// request grammar (no `+`, no spaces); for a number, the value as
    /// sent too, for the range check.
    fn parse_like(self, text: &str) -> Option<(Value, Option<Number<'_>>)> {
        match self {
            Value::Int(_) => {
                let n = Number::parse(text)?;
                text.parse().ok().map(|i| (Value::Int(i), Some(n)))
            }
            Value::Float(_) => Number::parse(text).map(|n| (Value::Float(n.value()), Some(n))),
            Value::Bool(_) => match text {
                "1" | "true" => Some((Value::Bool(true), None)),
                "0" | "false" => Some((Value::Bool(false), None)),
                _ => None,
            },
        }
    }

    /// Whether `text`, which [`Value::parse_like`] refused, is a number
    /// of this type's grammar that is too large for it (`1e39` for a
    /// float, `99999999999999999999` for an integer): out of range, not
    /// of the wrong type.
    fn too_large(self, text: &str) -> bool {
        let integer = |t: &str| {
            let digits = t.strip_prefix('-').unwrap_or(t);
            !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit())
        };
        match self {
            Value::Int(_) => integer(text),
            Value::Float(_) => parse_f32(text).is_some_and(f32::is_infinite),
            Value::Bool(_) => false,
        }
    }

    fn json_like(self, v: &serde_json::Value) -> Option<Value> {
        match self {
            Value::Int(_) => v.as_i64().map(Value::Int),
            Value::Float(_) => v
                .as_f64()
                .map(|f| f as f32)
                .filter(|f| f.is_finite())
                .map(Value::Float),
            Value::Bool(_) => v.as_bool().map(Value::Bool),
        }
    }

    fn to_json(self) -> serde_json::Value {
        match self {
            Value::Int(i) => i.into(),
            Value::Float(_) => self.as_f64().into(),
            Value::Bool(b) => b.into(),
        }
    }

    /// Writes the value as a member of a response object.
    pub(crate) fn write(self, out: &mut Fields<'_>, key: &str) {
        match self {
            Value::Int(i) => out.i64(key, i),
            Value::Float(f) => out.f32(key, f),
            Value::Bool(b) => out.bool(key, b),
        };
    }
}

/// One parameter's definition.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Def {
    /// The typed key the simulator reads it by.
    key: Key,
    /// Its name on the wire.
    name: &'static str,
    /// Its default, which also fixes its type.
    default: Value,
    /// Smallest allowed value (ignored for booleans).
    min: f64,
    /// Largest allowed value (ignored for booleans).
    max: f64,
    /// What it does, with its unit.
    doc: &'static str,
}

macro_rules! params {
    ($( $key:ident $name:literal $default:expr, $min:literal ..= $max:literal, $doc:literal; )*) => {
        /// A parameter the simulator reads.
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        pub(crate) enum Key { $( #[doc = $doc] $key, )* }

        /// Every parameter, in `Key` order.
        static DEFS: &[Def] = &[
            $( Def { key: Key::$key, name: $name, default: $default, min: $min, max: $max, doc: $doc }, )*
        ];
    };
}

params! {
    TakeoffAlt "takeoff_alt" Value::Float(2.0), 0.5..=120.0, "Takeoff altitude above home, m.";
    ClimbSpeed "climb_speed" Value::Float(1.0), 0.1..=5.0, "Vertical speed when climbing, m/s.";
    LandSpeed "land_speed" Value::Float(0.7), 0.2..=3.0, "Slowest landing descent, m/s (faster from high up, so that landing takes at most 12 s).";
    CruiseSpeed "cruise_speed" Value::Float(2.0), 0.1..=15.0, "Horizontal speed towards setpoints and waypoints, m/s.";
    YawRate "yaw_rate" Value::Float(1.0), 0.1..=6.3, "Largest yaw rate, rad/s.";
    AcceptRadius "accept_radius" Value::Float(0.3), 0.05..=10.0, "Distance at which a waypoint counts as reached, m.";
    RtlAlt "rtl_alt" Value::Float(10.0), 2.0..=120.0, "Altitude the vehicle climbs to (if lower) before returning home, m.";
    RtlLand "rtl_land" Value::Bool(true), 0.0..=1.0, "Whether RTL lands at home (otherwise it hovers there).";
    MaxAlt "max_alt" Value::Float(120.0), 1.0..=500.0, "Highest target altitude above home (setpoints, waypoints, zyhk heights; takeoff and RTL climb at most this high), m.";
    GeofenceRadius "geofence_radius" Value::Float(500.0), 1.0..=10000.0, "Largest horizontal distance from home of a target, m.";
    BatteryDrain "battery_drain" Value::Float(1.0), 0.0..=100.0, "Battery drain while armed, percent per minute.";
    LowBattery "low_battery" Value::Float(20.0), 0.0..=90.0, "Battery percentage below which a flying vehicle returns home.";
    ZyhkHover "zyhk_hover" Value::Float(5.0), 0.0..=600.0, "Hover time at each zyhk height, s.";
    AutosleepAfter "autosleep_after" Value::Int(300), 10.0..=86400.0, "Disarmed time before auto-sleep (when enabled), s.";
    MavlinkRate "mavlink_rate" Value::Int(50), 1.0..=400.0, "Rate of the simulated ATTITUDE stream, Hz.";
    MinAlt "min_alt" Value::Float(0.5), 0.2..=10.0, "Lowest target altitude above home (setpoints, waypoints, zyhk heights; takeoff climbs at least this high), m.";
    ControlTimeout "control_timeout" Value::Int(30), 1.0..=3600.0, "Seconds without a request after which the session in control loses it.";
}

/// The working and saved parameter values.
#[derive(Debug)]
pub(crate) struct Params {
    values: Vec<Value>,
    saved: Vec<Value>,
    file: PathBuf,
}

impl Params {
    /// Loads `file` if it exists; parameters it lacks keep their defaults.
    /// Unknown names and unusable values in the file are skipped with a
    /// warning, so that an older or newer daemon can still start.
    pub(crate) fn load(file: PathBuf) -> io::Result<Params> {
        let saved = read_file(&file)?;
        Ok(Params {
            values: saved.clone(),
            saved,
            file,
        })
    }

    /// The working value of `key`.
    fn value(&self, key: Key) -> Value {
        self.values.get(key as usize).copied().unwrap_or(Value::Int(0))
    }

    /// The working value of `key` as a number.
    pub(crate) fn f64(&self, key: Key) -> f64 {
        self.value(key).as_f64()
    }

    /// The working value of a boolean `key`.
    pub(crate) fn flag(&self, key: Key) -> bool {
        self.value(key) == Value::Bool(true)
    }

    /// The definition and working value of the parameter called `name`.
    fn get(&self, name: &str) -> SimResult<(&'static Def, Value)> {
        let def = DEFS
            .iter()
            .find(|d| d.name == name)
            .ok_or_else(|| SimError::UnknownParam(name.into()))?;
        Ok((def, self.value(def.key)))
    }

    /// Whether the working value of `def` differs from the saved one.
    fn unsaved(&self, def: &Def) -> bool {
        self.values.get(def.key as usize) != self.saved.get(def.key as usize)
    }

    /// Sets the working value of `name` from its text (ret -2 for an
    /// unknown name, a value of the wrong type or out of range).
    fn set(&mut self, name: &str, text: &str) -> SimResult<Value> {
        let (def, _) = self.get(name)?;
        let out_of_range = |value: String| SimError::ParamRange {
            name: name.into(),
            value,
            min: def.min,
            max: def.max,
        };
        let Some((value, sent)) = def.default.parse_like(text) else {
            if def.default.too_large(text) {
                // Echoed as sent when short; a long one is only "too large".
                let shown = if text.len() <= 24 {
                    text
                } else {
                    "(a number too large)"
                };
                return Err(out_of_range(shown.into()));
            }
            return Err(SimError::ParamType {
                name: name.into(),
                expected: def.default.type_name(),
                value: text.into(),
            });
        };
        if let Some(n) = sent.filter(|n| !sent_in_range(def, n)) {
            return Err(out_of_range(n.to_string()));
        }
        self.check_envelope(def.key, value.as_f64())?;
        if let Some(slot) = self.values.get_mut(def.key as usize) {
            *slot = value;
        }
        Ok(value)
    }

    /// The one relation between parameters `set_param` enforces: `min_alt`
    /// stays below `max_alt`, or no target could be flown (DESIGN.md,
    /// "Flight authority"). Every other relation is settled by clipping
    /// (`takeoff_alt` and `rtl_alt` into the envelope).
    fn check_envelope(&self, key: Key, value: f64) -> SimResult {
        let (min, max) = match key {
            Key::MinAlt => (value, self.f64(Key::MaxAlt)),
            Key::MaxAlt => (self.f64(Key::MinAlt), value),
            _ => return Ok(()),
        };
        if min < max {
            return Ok(());
        }
        Err(SimError::Refused(format!(
            "min_alt {min} m not below max_alt {max} m: no altitude would be left to fly"
        )))
    }

    /// Every working value back to its default (not saved until `save`).
    fn reset(&mut self) {
        self.values = defaults();
    }

    /// Persists the working values atomically.
    fn save(&mut self) -> io::Result<()> {
        let map: serde_json::Map<String, serde_json::Value> = DEFS
            .iter()
            .map(|d| (d.name.to_owned(), self.value(d.key).to_json()))
            .collect();
        let text = serde_json::to_vec_pretty(&map).map_err(io::Error::other)?;
        atomic_write(&self.file, &text, 0o644)?;
        self.saved = self.values.clone();
        Ok(())
    }

    /// Writes every parameter as `name: value` members.
    fn write_all(&self, out: &mut Fields<'_>) {
        for def in DEFS {
            self.value(def.key).write(out, def.name);
        }
    }

    /// `param`, `get_param`, `set_param`, `reset_param`, `save_param`.
    pub(crate) fn run(&mut self, cmd: &Command<'_>, out: &mut Fields<'_>) -> SimResult {
        match (cmd.id(), cmd.args()) {
            (CommandId::GetParam, Args::ParamName(name)) => self.write_one(name, out)?,
            (CommandId::SetParam, Args::SetParam { name, value }) => {
                let v = self.set(name, value)?;
                tracing::info!(param = name, value, "parameter set");
                // As get_param and save_param 0 say: setting the saved value
                // back leaves nothing unsaved.
                let (def, _) = self.get(name)?;
                out.object("param", |o| v.write(o, name))
                    .bool("unsaved", self.unsaved(def));
            }
            (CommandId::ResetParam, _) => {
                self.reset();
                tracing::info!("parameters reset to defaults (unsaved)");
                out.object("param", |o| self.write_all(o));
            }
            (CommandId::SaveParam, &Args::Flag(true)) => {
                self.save().map_err(|e| SimError::io("save parameters", e))?;
                tracing::info!("parameters saved");
                out.bool("saved", true).str("file", PARAMS_FILE);
            }
            (CommandId::SaveParam, _) => {
                let unsaved: Vec<_> = DEFS.iter().filter(|d| self.unsaved(d)).map(|d| d.name).collect();
                out.bool("saved", false).array("unsaved", |a| {
                    unsaved.iter().for_each(|n| {
                        a.str(n);
                    })
                });
            }
            _ => {
                out.object("param", |o| self.write_all(o));
            }
        }
        Ok(())
    }

    fn write_one(&self, name: &str, out: &mut Fields<'_>) -> SimResult {
        let (def, value) = self.get(name)?;
        out.object("param", |o| value.write(o, def.name));
        out.object("info", |o| {
            o.str("type", def.default.type_name());
            def.default.write(o, "default");
            o.f64("min", def.min)
                .f64("max", def.max)
                .bool("unsaved", self.unsaved(def))
                .str("doc", def.doc);
        });
        Ok(())
    }
}

fn defaults() -> Vec<Value> {
    DEFS.iter().map(|d| d.default).collect()
}

fn in_range(def: &Def, value: Value) -> bool {
    matches!(value, Value::Bool(_)) || (def.min..=def.max).contains(&value.as_f64())
}

/// Whether a number as sent is in `def`'s range, exactly (`120.0000001`
/// is above 120 although its `f32` is 120): the bounds as the decimals they
/// are written as.
fn sent_in_range(def: &Def, n: &Number<'_>) -> bool {
    use std::cmp::Ordering::{Greater, Less};
    let below = n.cmp_decimal(&def.min.to_string()) == Some(Less);
    let above = n.cmp_decimal(&def.max.to_string()) == Some(Greater);
    !(below || above)
}

fn read_file(file: &Path) -> io::Result<Vec<Value>> {
    let mut values = defaults();
    let text = match std::fs::read(file) {
        Ok(t) => t,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(values),
        Err(e) => return Err(e),
    };
    let map: serde_json::Map<String, serde_json::Value> = serde_json::from_slice(&text)
        .map_err(|e| io::Error::new(io::ErrorKind::InvalidData, format!("{}: {e}", file.display())))?;
    for (name, json) in &map {
        let def = DEFS.iter().find(|d| d.name == name);
        match def.and_then(|d| Some((d, d.default.json_like(json)?))) {
            Some((def, value)) if in_range(def, value) => values[def.key as usize] = value,
            _ => {
                tracing::warn!(file = %file.display(), param = %name, value = %json, "ignoring saved parameter")
            }
        }
    }
    let (min, max) = (
        values[Key::MinAlt as usize].as_f64(),
        values[Key::MaxAlt as usize].as_f64(),
    );
    if min >= max {
        tracing::warn!(file = %file.display(), min_alt = min, max_alt = max, "saved min_alt not below max_alt: both back to their defaults");
        values[Key::MinAlt as usize] = DEFS[Key::MinAlt as usize].default;
        values[Key::MaxAlt as usize] = DEFS[Key::MaxAlt as usize].default;
    }
    Ok(values)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_index_their_own_definitions() {
        for (i, def) in DEFS.iter().enumerate() {
            assert_eq!(def.key as usize, i, "{}", def.name);
            assert!(in_range(def, def.default), "{} default out of range", def.name);
        }
    }

    #[test]
    fn set_checks_type_then_range() {
        let dir = tempfile::tempdir().unwrap();
        let mut p = Params::load(dir.path().join("params.json")).unwrap();
        assert_eq!(p.set("takeoff_alt", "3").unwrap(), Value::Float(3.0));
        assert_eq!(p.set("autosleep_after", "60").unwrap(), Value::Int(60));
        assert_eq!(p.set("rtl_land", "false").unwrap(), Value::Bool(false));
        let e = p.set("autosleep_after", "1.5").unwrap_err();
        assert_eq!(
            e.to_string(),
            "Invalid arguments: autosleep_after expects int, got '1.5'"
        );
        let e = p.set("takeoff_alt", "121").unwrap_err();
        assert_eq!(
            e.to_string(),
            "Invalid arguments: takeoff_alt 121 out of range 0.5..120"
        );
        assert!(matches!(
            p.set("takeoff_alt", "NaN"),
            Err(SimError::ParamType { .. })
        ));
        // Too large for its type is out of range, not of the wrong type.
        assert_eq!(
            p.set("takeoff_alt", "1e39").unwrap_err().to_string(),
            "Invalid arguments: takeoff_alt 1e39 out of range 0.5..120"
        );
        assert_eq!(
            p.set("autosleep_after", "99999999999999999999")
                .unwrap_err()
                .to_string(),
            "Invalid arguments: autosleep_after 99999999999999999999 out of range 10..86400"
        );
        assert!(matches!(
            p.set("autosleep_after", "1e3"),
            Err(SimError::ParamType { .. })
        ));
        assert_eq!(
            p.set("nope", "1").unwrap_err().to_string(),
            "Invalid arguments: unknown parameter nope"
        );
        assert_eq!(p.f64(Key::TakeoffAlt), 3.0);
    }

    #[test]
    fn values_follow_the_request_number_grammar_and_ranges_are_checked_as_sent() {
        let dir = tempfile::tempdir().unwrap();
        let mut p = Params::load(dir.path().join("params.json")).unwrap();
        for bad in [" 3", "+3", "3 ", "0x3", "3,5"] {
            assert!(
                matches!(p.set("takeoff_alt", bad), Err(SimError::ParamType { .. })),
                "{bad:?}"
            );
        }
        assert!(matches!(
            p.set("autosleep_after", "+60"),
            Err(SimError::ParamType { .. })
        ));
        assert!(matches!(p.set("rtl_land", " 1"), Err(SimError::ParamType { .. })));
        let e = p.set("takeoff_alt", "120.0000001").unwrap_err();
        assert_eq!(
            e.to_string(),
            "Invalid arguments: takeoff_alt 120.0000001 out of range 0.5..120"
        );
        assert!(p.set("takeoff_alt", "120.0000000").is_ok());
        assert!(matches!(
            p.set("accept_radius", "0.0499999999"),
            Err(SimError::ParamRange { .. })
        ));
        assert!(
            p.set("accept_radius", "0.05").is_ok(),
            "the bound is the decimal 0.05"
        );
        // An f32 parameter keeps (and answers) an f32.
        let v = p.set("takeoff_alt", "2.123456789012345678901").unwrap();
        assert_eq!(v, Value::Float(2.123_456_7));
        assert_eq!(p.f64(Key::TakeoffAlt), 2.123_456_7);
    }

    #[test]
    fn saved_values_survive_a_reload_and_unsaved_ones_do_not() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("params.json");
        let mut p = Params::load(file.clone()).unwrap();
        p.set("cruise_speed", "4.5").unwrap();
        p.save().unwrap();
        p.set("cruise_speed", "1").unwrap();
        assert_eq!(p.f64(Key::CruiseSpeed), 1.0);
        let reloaded = Params::load(file).unwrap();
        assert_eq!(reloaded.f64(Key::CruiseSpeed), 4.5);
        assert_eq!(reloaded.f64(Key::TakeoffAlt), 2.0);
    }

    #[test]
    fn unusable_saved_values_fall_back_to_defaults() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("params.json");
        std::fs::write(
            &file,
            r#"{"takeoff_alt": 999, "climb_speed": 2.5, "future_param": 1, "rtl_land": 3}"#,
        )
        .unwrap();
        let p = Params::load(file).unwrap();
        assert_eq!(p.f64(Key::TakeoffAlt), 2.0);
        assert_eq!(p.f64(Key::ClimbSpeed), 2.5);
        assert!(p.flag(Key::RtlLand));
    }
}
