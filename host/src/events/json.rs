//! Events as the JSON objects subscribers get: `{"event":"<name>","seq":N,
//! "boot":"<id>","ts":ms, ...fields}` (DESIGN.md, "Events"), and the `gap`
//! a slow subscriber gets instead of what it missed.

use serde_json::{Map, Value, json};

use super::{Event, MissionStatus};

/// The object of `event`, numbered `seq` in run `boot`, at `ts`.
pub fn render(event: &Event, seq: u64, boot: &str, ts: i64) -> String {
    let mut o = Map::new();
    o.insert("event".into(), event.name().into());
    o.insert("seq".into(), seq.into());
    o.insert("boot".into(), boot.into());
    o.insert("ts".into(), ts.into());
    fields(event, &mut o);
    Value::Object(o).to_string()
}

/// `{"event":"gap","missed":N,"ts":ms}`: `missed` events were dropped
/// before the next one this subscriber gets (no `seq` of its own).
pub fn gap(missed: u64, ts: i64) -> String {
    json!({"event": "gap", "missed": missed, "ts": ts}).to_string()
}

fn fields(event: &Event, o: &mut Map<String, Value>) {
    let mut put = |k: &str, v: Value| {
        o.insert(k.into(), v);
    };
    match event {
        Event::Fsm { from, to } => {
            put("from", (*from).into());
            put("to", (*to).into());
        }
        Event::Armed { armed } => put("armed", (*armed).into()),
        Event::Mission { ext_id, status } => {
            put("ext_id", (*ext_id).into());
            let name = match status {
                MissionStatus::Started => "started",
                MissionStatus::Reached { .. } => "reached",
                MissionStatus::Completed => "completed",
                MissionStatus::Aborted => "aborted",
            };
            put("status", name.into());
            if let MissionStatus::Reached { wp, index, count } = status {
                put("wp", (*wp).into());
                put("index", (*index).into());
                put("count", (*count).into());
            }
        }
        Event::Failsafe {
            reason,
            action,
            overridden,
        } => {
            put("reason", reason.clone().into());
            put("action", (*action).into());
            put("overridden", (*overridden).into());
        }
        Event::Control { by, from } => {
            put("by", by.clone().into());
            put("from", from.clone().into());
        }
        Event::Battery { percent } => put("percent", one_decimal(*percent)),
        Event::Link { up } => put("state", if *up { "up" } else { "lost" }.into()),
        Event::Uplink { up } => put("state", if *up { "up" } else { "down" }.into()),
        Event::Log { level, msg } => {
            put("level", (*level).into());
            put("msg", msg.clone().into());
        }
    }
}

/// `v` rounded to one decimal, as JSON (`19.9`, `0`, never `-0`).
fn one_decimal(v: f64) -> Value {
    let r = (v * 10.0).round() / 10.0 + 0.0;
    if r.fract() == 0.0 && r.abs() < 1e15 {
        (r as i64).into()
    } else {
        r.into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_event_has_its_fields_after_the_common_ones() {
        let cases = [
            (
                Event::Fsm {
                    from: "hover",
                    to: "mission",
                },
                r#""from":"hover","to":"mission""#,
            ),
            (
                Event::Mission {
                    ext_id: 7,
                    status: MissionStatus::Reached {
                        wp: 4,
                        index: 2,
                        count: 3,
                    },
                },
                r#""ext_id":7,"status":"reached","wp":4,"index":2,"count":3"#,
            ),
            (
                Event::Mission {
                    ext_id: 7,
                    status: MissionStatus::Completed,
                },
                r#""ext_id":7,"status":"completed""#,
            ),
            (
                Event::Failsafe {
                    reason: Some("battery_low".into()),
                    action: "rtl",
                    overridden: false,
                },
                r#""reason":"battery_low","action":"rtl","overridden":false"#,
            ),
            (
                Event::Failsafe {
                    reason: None,
                    action: "none",
                    overridden: false,
                },
                r#""reason":null,"action":"none","overridden":false"#,
            ),
            (
                Event::Control {
                    by: Some("mqtt alice".into()),
                    from: None,
                },
                r#""by":"mqtt alice","from":null"#,
            ),
            (Event::Battery { percent: 19.94 }, r#""percent":19.9"#),
            (Event::Battery { percent: -0.01 }, r#""percent":0"#),
            (Event::Link { up: false }, r#""state":"lost""#),
            (Event::Uplink { up: false }, r#""state":"down""#),
            (
                Event::Log {
                    level: "warning",
                    msg: "battery low: \"rtl\"".into(),
                },
                r#""level":"warning","msg":"battery low: \"rtl\"""#,
            ),
        ];
        for (event, tail) in cases {
            let name = event.name();
            assert_eq!(
                render(&event, 3, "ab", 5),
                format!(r#"{{"event":"{name}","seq":3,"boot":"ab","ts":5,{tail}}}"#)
            );
        }
        assert_eq!(gap(12, 9), r#"{"event":"gap","missed":12,"ts":9}"#);
    }
}
