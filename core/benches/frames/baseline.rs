//! The baseline: the same protocol work written the straightforward std
//! way — `str` splitting, `String`s, a `HashMap` of commands and
//! `serde_json::Value` responses. It reads command facts from core's table
//! (one table per fact) but none of core's parsing or writing code.

use std::collections::HashMap;

use lluav_core::{Flags, Grammar, TABLE};
use serde_json::{Value, json};

struct Info {
    id: u8,
    flags: Flags,
    grammar: Grammar,
    usage: String,
}

/// A vehicle-wide server, as a first implementation would write it.
pub struct Baseline {
    commands: HashMap<String, Info>,
    password: Option<String>,
    pub armed: bool,
    lock: bool,
}

/// One connection.
#[derive(Default)]
pub struct BaselineSession {
    logged_in: bool,
    admin: bool,
}

fn error(ret: i64, cmd: u8, ts: i64, msg: String) -> String {
    json!({"ret": ret, "cmd": cmd, "ts": ts, "msg": msg}).to_string()
}

fn number(s: &str) -> Option<f64> {
    s.parse::<f64>().ok().filter(|v| v.is_finite())
}

impl Baseline {
    pub fn new(password: Option<&str>) -> Self {
        let commands = TABLE
            .iter()
            .map(|s| {
                let info = Info {
                    id: u8::from(s.id),
                    flags: s.flags,
                    grammar: s.grammar,
                    usage: s.usage.to_string(),
                };
                (s.name().to_string(), info)
            })
            .collect();
        Baseline {
            commands,
            password: password.map(String::from),
            armed: false,
            lock: false,
        }
    }

    pub fn handle(&mut self, session: &mut BaselineSession, frame: &str) -> String {
        let ts = 1_714_233_600_000_i64;
        let frame = frame.trim_end_matches([' ', '\r', '\n']).to_string();
        let parts: Vec<String> = frame.splitn(2, ' ').map(String::from).collect();
        let name = parts[0].clone();
        let args = parts.get(1).cloned();
        let info = self.commands.get(&name);
        let cmd = info.map_or(0, |i| i.id);
        if self.password.is_some() && !session.logged_in && name != "login" {
            return error(-1, cmd, ts, "Login first!".to_string());
        }
        let Some(info) = info else {
            return error(
                -2,
                0,
                ts,
                format!(
                    "Unsupported command: {}",
                    name.chars().take(32).collect::<String>()
                ),
            );
        };
        if info.flags.admin_only() && !session.admin {
            return error(-1, cmd, ts, "Admin only!".into());
        }
        if !info.flags.run_on_arm() && self.armed {
            return error(-1, cmd, ts, "Not allow when vehicle is ARMED!".into());
        }
        if !info.flags.run_in_lock() && self.lock && !session.admin {
            return error(-1, cmd, ts, "CMD not permitted to run in LOCK mode!".into());
        }
        let invalid = || error(-2, cmd, ts, format!("Invalid arguments, usage: {}", info.usage));
        let mut response = json!({"ret": 0, "cmd": cmd, "ts": ts});
        let fields = response.as_object_mut().expect("an object");
        match (info.grammar, args) {
            (Grammar::None, None) if name == "state" => {
                fields.insert(
                    "state".into(),
                    json!({
                        "armed": self.armed, "fsm": "hover", "lock_mode": self.lock,
                        "x": 1.5, "y": -2.25, "z": -10.0, "vx": 0.0, "vy": 0.1, "vz": 0.0,
                        "yaw": 0.5, "battery": 87.5
                    }),
                );
            }
            (Grammar::None, None) => {}
            (Grammar::Secret, Some(pw)) => {
                if pw == "1025" {
                    session.logged_in = true;
                    session.admin = true;
                } else if Some(&pw) == self.password.as_ref() {
                    session.logged_in = true;
                } else {
                    return error(-1, cmd, ts, "Wrong password!".into());
                }
            }
            (Grammar::Setpoint, Some(a)) => {
                let values: Vec<Option<f64>> = a.split(':').map(number).collect();
                if values.len() != 4 || values.iter().any(Option::is_none) {
                    return invalid();
                }
                let v: Vec<f64> = values.into_iter().flatten().collect();
                fields.insert("x".into(), json!(v[0]));
                fields.insert("y".into(), json!(v[1]));
                fields.insert("z".into(), json!(v[2]));
                fields.insert("yaw".into(), json!(v[3]));
            }
            (Grammar::MwExec, Some(a)) => {
                let Some((ext, ids)) = a.split_once(':') else {
                    return invalid();
                };
                let Ok(ext) = ext.parse::<u32>() else {
                    return invalid();
                };
                let ids: Result<Vec<u32>, _> = ids.split(',').map(str::parse::<u32>).collect();
                let Ok(ids) = ids else { return invalid() };
                if ids.is_empty() || ids.len() > 64 {
                    return invalid();
                }
                fields.insert("ext_id".into(), json!(ext));
                fields.insert("wp_ids".into(), json!(ids));
            }
            (Grammar::Mission, Some(a)) => {
                let Some((ext, payload)) = a.split_once(':') else {
                    return invalid();
                };
                let Ok(ext) = ext.parse::<u32>() else {
                    return invalid();
                };
                if payload.starts_with(['{', '[']) {
                    let Ok(v) = serde_json::from_str::<Value>(payload) else {
                        return invalid();
                    };
                    let n = v.get("waypoints").and_then(Value::as_array).map_or(0, Vec::len);
                    fields.insert("waypoints".into(), json!(n));
                } else if payload.split('/').any(|c| c.is_empty() || c == "..") {
                    return invalid();
                }
                fields.insert("ext_id".into(), json!(ext));
            }
            _ => return invalid(),
        }
        response.to_string()
    }
}
