//! Property tests: every command round-trips through its text, and any
//! input gets exactly one valid JSON response, never a panic.

mod common;

use common::*;
use heapless::Vec as HVec;
use lluav_core::{
    Args, Command, Grammar, LandPoint, MAX_HEIGHTS, MAX_WAYPOINT_IDS, Message, Outcome, Payload, Point, Pose,
    Session, Step, TABLE, parse,
};
use proptest::prelude::*;

/// An owned mirror of `Args`, so generated strings outlive the command
/// that borrows them.
#[derive(Clone, Debug)]
enum Owned {
    None,
    Flag(bool),
    OptCount(Option<u32>),
    Pwm(u16),
    Amount(f32),
    OptAmount(Option<f32>),
    Angle(f32),
    Name(String),
    OptName(Option<String>),
    Path(String),
    Text(String),
    TaskName(String),
    Secret(String),
    NewPassword(String),
    ParamName(String),
    SetParam(String, String),
    Setpoint([f32; 4]),
    Point([f32; 3]),
    Pose([f32; 4]),
    Zyhk(Vec<f32>, Option<[f32; 3]>),
    Mission(u32, bool, String),
    MwExec(u32, Vec<u32>),
    Ai1Mission(String, String),
    Override(bool),
}

impl Owned {
    fn args(&self) -> Args<'_> {
        match self {
            Owned::None => Args::None,
            Owned::Flag(b) => Args::Flag(*b),
            Owned::OptCount(n) => Args::OptCount(*n),
            Owned::Pwm(n) => Args::Pwm(*n),
            Owned::Amount(v) => Args::Amount((*v).into()),
            Owned::OptAmount(v) => Args::OptAmount(v.map(Into::into)),
            Owned::Angle(v) => Args::Angle(*v),
            Owned::Name(s) => Args::Name(s),
            Owned::OptName(s) => Args::OptName(s.as_deref()),
            Owned::Path(s) => Args::Path(s),
            Owned::Text(s) => Args::Text(s),
            Owned::TaskName(s) => Args::TaskName(s),
            Owned::Secret(s) => Args::Secret(s),
            Owned::NewPassword(s) => Args::NewPassword(s),
            Owned::ParamName(s) => Args::ParamName(s),
            Owned::SetParam(n, v) => Args::SetParam { name: n, value: v },
            Owned::Setpoint([x, y, z, yaw]) => Args::Setpoint(Pose {
                x: *x,
                y: *y,
                z: *z,
                yaw: *yaw,
            }),
            Owned::Point([x, y, z]) => Args::Point(Point { x: *x, y: *y, z: *z }),
            Owned::Pose([x, y, z, yaw]) => Args::Pose(Pose {
                x: *x,
                y: *y,
                z: *z,
                yaw: *yaw,
            }),
            Owned::Zyhk(h, land) => Args::Zyhk {
                heights: HVec::<f32, MAX_HEIGHTS>::from_slice(h).unwrap(),
                land: land.map(|[x, y, yaw]| LandPoint { x, y, yaw }),
            },
            Owned::Mission(id, json, p) => Args::Mission {
                ext_id: *id,
                payload: if *json { Payload::Json(p) } else { Payload::Path(p) },
            },
            Owned::MwExec(id, ids) => Args::MwExec {
                ext_id: *id,
                wp_ids: HVec::<u32, MAX_WAYPOINT_IDS>::from_slice(ids).unwrap(),
            },
            Owned::Ai1Mission(t, f) => Args::Ai1Mission { task_id: t, file: f },
            Owned::Override(on) => Args::Override(*on),
        }
    }
}

fn finite() -> impl Strategy<Value = f32> {
    prop_oneof![
        any::<f32>().prop_filter("finite", |v| v.is_finite()),
        -1000f32..1000f32,
        Just(0.0f32),
        Just(-0.0f32),
        Just(f32::MAX),
        Just(f32::MIN_POSITIVE),
        Just(1e-45f32),
    ]
}

fn non_negative() -> impl Strategy<Value = f32> {
    finite().prop_map(f32::abs)
}

/// A setpoint's z: above the ground, so below 0.
fn up() -> impl Strategy<Value = f32> {
    finite().prop_filter_map("above the ground", |v| Some(-v.abs()).filter(|&z| z < 0.0))
}

const NAME: &str = "[A-Za-z0-9_é]([A-Za-z0-9_. é-]{0,20}[A-Za-z0-9_é])?";
const TEXT: &str = "[ -~é🚁]{0,30}[!-~é🚁]";

fn path() -> impl Strategy<Value = String> {
    prop::collection::vec(NAME, 1..4).prop_map(|v| v.join("/"))
}

fn json() -> impl Strategy<Value = String> {
    let leaf = prop_oneof![
        Just(serde_json::Value::Null),
        any::<bool>().prop_map(serde_json::Value::from),
        any::<i64>().prop_map(serde_json::Value::from),
        (-1e9f64..1e9).prop_map(serde_json::Value::from),
        "\\PC{0,8}".prop_map(serde_json::Value::from),
    ];
    let value = leaf.prop_recursive(4, 32, 6, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..6).prop_map(serde_json::Value::from),
            prop::collection::btree_map("\\PC{0,6}", inner, 0..6)
                .prop_map(|m| serde_json::Value::Object(m.into_iter().collect())),
        ]
    });
    let container = prop_oneof![
        prop::collection::vec(value.clone(), 0..4).prop_map(serde_json::Value::from),
        prop::collection::btree_map("[a-z]{1,6}", value, 0..4)
            .prop_map(|m| serde_json::Value::Object(m.into_iter().collect())),
    ];
    (container, any::<bool>()).prop_map(|(v, pretty)| {
        if pretty {
            serde_json::to_string_pretty(&v).unwrap()
        } else {
            v.to_string()
        }
    })
}

fn owned_args(g: Grammar) -> BoxedStrategy<Owned> {
    match g {
        Grammar::None => Just(Owned::None).boxed(),
        Grammar::Flag => any::<bool>().prop_map(Owned::Flag).boxed(),
        Grammar::OptCount => any::<Option<u32>>().prop_map(Owned::OptCount).boxed(),
        Grammar::Pwm => any::<u16>().prop_map(Owned::Pwm).boxed(),
        Grammar::Amount => non_negative().prop_map(Owned::Amount).boxed(),
        Grammar::OptAmount => prop::option::of(non_negative())
            .prop_map(Owned::OptAmount)
            .boxed(),
        Grammar::Angle => (-90f32..=90f32).prop_map(Owned::Angle).boxed(),
        Grammar::Name => NAME.prop_map(Owned::Name).boxed(),
        Grammar::OptName => prop::option::of(NAME).prop_map(Owned::OptName).boxed(),
        Grammar::Path => path().prop_map(Owned::Path).boxed(),
        Grammar::Text => TEXT.prop_map(Owned::Text).boxed(),
        Grammar::TaskName => TEXT.prop_map(Owned::TaskName).boxed(),
        Grammar::Secret => TEXT.prop_map(Owned::Secret).boxed(),
        Grammar::NewPassword => "[!-~]{1,32}"
            .prop_filter("not a special login value", |p| p != "1025" && p != "0315")
            .prop_map(Owned::NewPassword)
            .boxed(),
        Grammar::ParamName => "[A-Za-z0-9_.-]{1,64}".prop_map(Owned::ParamName).boxed(),
        Grammar::SetParam => ("[A-Za-z0-9_.-]{1,64}", TEXT)
            .prop_map(|(n, v)| Owned::SetParam(n, v))
            .boxed(),
        Grammar::Setpoint => (finite(), finite(), up(), finite())
            .prop_map(|(x, y, z, yaw)| Owned::Setpoint([x, y, z, yaw]))
            .boxed(),
        Grammar::Point => [finite(), finite(), finite()].prop_map(Owned::Point).boxed(),
        Grammar::Pose => [finite(), finite(), finite(), finite()]
            .prop_map(Owned::Pose)
            .boxed(),
        Grammar::Zyhk => (
            prop::collection::vec(finite(), 1..=MAX_HEIGHTS),
            prop::option::of([finite(), finite(), finite()]),
        )
            .prop_map(|(h, l)| Owned::Zyhk(h, l))
            .boxed(),
        Grammar::Mission => (
            any::<u32>(),
            prop_oneof![json().prop_map(|j| (true, j)), path().prop_map(|p| (false, p))],
        )
            .prop_map(|(id, (is_json, p))| Owned::Mission(id, is_json, p))
            .boxed(),
        Grammar::MwExec => (
            any::<u32>(),
            prop::collection::vec(any::<u32>(), 1..=MAX_WAYPOINT_IDS),
        )
            .prop_map(|(id, ids)| Owned::MwExec(id, ids))
            .boxed(),
        Grammar::Ai1Mission => ("[A-Za-z0-9_-]{1,64}", path())
            .prop_map(|(t, f)| Owned::Ai1Mission(t, f))
            .boxed(),
        Grammar::Override => any::<bool>().prop_map(Owned::Override).boxed(),
    }
}

fn any_command() -> impl Strategy<Value = (usize, Owned)> {
    (0..TABLE.len()).prop_flat_map(|row| (Just(row), owned_args(TABLE[row].grammar)))
}

/// A frame that is near-valid: a generated command with a few edits.
fn mutated_frame() -> impl Strategy<Value = String> {
    (
        any_command(),
        prop::collection::vec((any::<prop::sample::Index>(), any::<char>(), 0..3u8), 0..4),
    )
        .prop_map(|((row, owned), edits)| {
            let cmd = Command::new(TABLE[row].id, owned.args()).unwrap();
            let mut chars: Vec<char> = cmd.to_string().chars().collect();
            for (at, c, op) in edits {
                let i = at.index(chars.len() + 1);
                match op {
                    0 => chars.insert(i, c),
                    1 if i < chars.len() => {
                        chars.remove(i);
                    }
                    _ if i < chars.len() => chars[i] = c,
                    _ => chars.push(c),
                }
            }
            chars.into_iter().collect()
        })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 4096, ..ProptestConfig::default() })]

    #[test]
    fn every_generated_command_round_trips_through_its_text((row, owned) in any_command()) {
        let spec = &TABLE[row];
        let cmd = Command::new(spec.id, owned.args())
            .unwrap_or_else(|e| panic!("generator made an invalid {}: {e:?} {owned:?}", spec.name()));
        let text = cmd.to_string();
        prop_assert_eq!(parse(&text), Ok(cmd.clone()), "text: {:?}", text);
        let mut small: heapless::String<8192> = heapless::String::new();
        cmd.encode(&mut small).unwrap();
        prop_assert_eq!(small.as_str(), text.as_str());
    }

    #[test]
    fn whatever_parses_encodes_back_to_the_same_command(frame in prop_oneof![mutated_frame(), "\\PC{0,80}", "[a-z_]{2,18}( [ -~]{0,40})?"]) {
        if let Ok(cmd) = parse(&frame) {
            let text = cmd.to_string();
            prop_assert_eq!(parse(&text), Ok(cmd.clone()), "from {:?}", frame);
            prop_assert_eq!(Command::new(cmd.id(), cmd.args().clone()), Ok(cmd));
        }
    }

    #[test]
    fn any_sequence_of_messages_gets_exactly_one_json_object_each(
        password in prop::option::of(Just("pw")),
        steps in prop::collection::vec(
            (
                prop_oneof![
                    mutated_frame().prop_map(String::into_bytes),
                    "\\PC{0,80}".prop_map(String::into_bytes),
                    Just(b"login pw".to_vec()),
                    Just(b"login 1025".to_vec()),
                    Just(b"admin_lock".to_vec()),
                    prop::collection::vec(any::<u8>(), 0..64),
                ],
                any::<bool>(),
            ),
            1..24,
        ),
    ) {
        let mut s = server(password);
        let mut sess = Session::new();
        let mut out = vec![0u8; 64 * 1024];
        for (bytes, armed) in steps {
            s.backend_mut().armed = armed;
            let valid_utf8 = std::str::from_utf8(&bytes).is_ok();
            match s.handle(&mut sess, Message::Text(&bytes), &mut out) {
                Outcome::Reply(r) => {
                    prop_assert!(valid_utf8);
                    checked_json(r);
                }
                Outcome::ReplyThenClose(r, code) => {
                    prop_assert_eq!(code.code(), 1008);
                    let v = checked_json(r);
                    prop_assert_eq!(v["msg"].as_str(), Some("Wrong password!"));
                    break;
                }
                Outcome::Close(code) => {
                    prop_assert!(!valid_utf8);
                    prop_assert_eq!(code.code(), 1007);
                }
                Outcome::Pending(t, _) => prop_assert!(false, "the mock vehicle never pends: {:?}", t),
            }
        }
    }
}

/// Writes the string it holds, as a key and as a value.
struct Say(String);

impl lluav_core::Backend for Say {
    fn armed(&self) -> bool {
        false
    }
    fn execute(
        &mut self,
        _: &Command<'_>,
        _: &lluav_core::Context,
        out: &mut lluav_core::Fields<'_>,
    ) -> Result<Step, lluav_core::Failure> {
        out.str("said", &self.0).object("nested", |o| {
            o.str(&self.0, &self.0);
        });
        Ok(Step::Done)
    }
}

proptest! {
    #[test]
    fn any_string_is_escaped_into_json_that_reads_back_the_same(text in prop_oneof!["\\PC{0,40}", ".{0,40}", "[\\x00-\\x7f]{0,40}"]) {
        let mut s = lluav_core::Server::new(Say(text.clone()), || 0_i64, lluav_core::Auth::new(None).unwrap());
        let mut sess = Session::new();
        let mut out = vec![0u8; 4096];
        let Outcome::Reply(r) = s.handle(&mut sess, Message::Text(b"state"), &mut out) else { panic!() };
        let v = checked_json(r);
        prop_assert_eq!(v["said"].as_str(), Some(text.as_str()));
        prop_assert_eq!(v["nested"][text.as_str()].as_str(), Some(text.as_str()));
    }
}
