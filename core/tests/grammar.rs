//! Valid and invalid argument forms of every command, through `parse` and
//! through the server (exact messages).

mod common;

use common::*;
use lluav_core::{ArgError, Args, Bound, CommandId, Grammar, ParseError, Payload, Session, TABLE, parse};

/// Invalid argument strings per grammar, with the typed reason.
fn invalid(g: Grammar) -> Vec<(Option<String>, ArgError)> {
    use ArgError::*;
    use Bound::{Angle, Float, Integer, NonNegative, Pwm};
    let c = |v: &[(&str, ArgError)]| {
        v.iter()
            .map(|(a, e)| (Some(a.to_string()), *e))
            .collect::<Vec<_>>()
    };
    let missing = vec![(None, Missing)];
    match g {
        Grammar::None => c(&[("x", Unexpected), ("0", Unexpected)]),
        Grammar::Flag => [
            missing,
            c(&[
                ("2", NotAFlag),
                ("true", NotAFlag),
                ("01", NotAFlag),
                (" 1", NotAFlag),
                ("+1", NotAFlag),
            ]),
        ]
        .concat(),
        Grammar::OptCount => c(&[
            ("-1", NotANumber),
            ("x", NotANumber),
            ("1.5", NotANumber),
            ("4294967296", OutOfRange(Integer)),
            ("+1", NotANumber),
            (" 1", NotANumber),
        ]),
        Grammar::Pwm => [
            missing,
            c(&[
                ("65536", OutOfRange(Pwm)),
                ("99999999999", OutOfRange(Pwm)),
                ("-1", NotANumber),
                ("1e3", NotANumber),
                ("+5", NotANumber),
            ]),
        ]
        .concat(),
        Grammar::Amount => [
            missing,
            c(&[
                ("-1", OutOfRange(NonNegative)),
                ("nan", NotANumber),
                ("inf", NotANumber),
                ("-Infinity", NotANumber),
                ("1e39", OutOfRange(Float)),
                ("-1e39", OutOfRange(Float)),
                ("abc", NotANumber),
                ("0x10", NotANumber),
                ("1,5", NotANumber),
                ("+1", NotANumber),
                ("+0", NotANumber),
                (" 1", NotANumber),
                ("1 5", NotANumber),
                ("1. 5", NotANumber),
                ("-1e-50", OutOfRange(NonNegative)),
                (
                    "-0.0000000000000000000000000000000000000000000000000001",
                    OutOfRange(NonNegative),
                ),
            ]),
        ]
        .concat(),
        Grammar::OptAmount => c(&[
            ("-0.5", OutOfRange(NonNegative)),
            ("NaN", NotANumber),
            ("x", NotANumber),
            ("+2", NotANumber),
        ]),
        Grammar::Angle => [
            missing,
            c(&[
                ("91", OutOfRange(Angle)),
                ("-90.5", OutOfRange(Angle)),
                ("inf", NotANumber),
                ("+45", NotANumber),
                ("90.000001", OutOfRange(Angle)),
                ("-90.0000001", OutOfRange(Angle)),
                ("90.00000000000000000000000000001", OutOfRange(Angle)),
                ("9.00000001e1", OutOfRange(Angle)),
            ]),
        ]
        .concat(),
        Grammar::Name => [
            missing,
            c(&[
                ("../x", UnsafePath),
                ("a/b", UnsafePath),
                ("..", UnsafePath),
                (".", UnsafePath),
                ("a\\b", UnsafePath),
                ("a\0b", UnsafePath),
                (" x", UnsafePath),
                ("a\tb", UnsafePath),
                (&"n".repeat(129), UnsafePath),
                (".hidden", UnsafePath),
                ("evil\u{202E}gpj.exe", UnsafePath),
                ("a\u{200B}b", UnsafePath),
                ("\u{FEFF}bom", UnsafePath),
                ("tag\u{E0041}", UnsafePath),
                ("del\u{7F}", UnsafePath),
                ("c1\u{85}", UnsafePath),
            ]),
        ]
        .concat(),
        Grammar::OptName => c(&[("../etc", UnsafePath), ("a/b", UnsafePath), (".x", UnsafePath)]),
        Grammar::Path => [
            missing,
            c(&[
                ("/etc/passwd", UnsafePath),
                ("a/../b", UnsafePath),
                ("a//b", UnsafePath),
                ("a/", UnsafePath),
                ("..", UnsafePath),
                ("a\\..\\b", UnsafePath),
                ("maps/.git", UnsafePath),
                ("a/b\u{202E}c", UnsafePath),
                (&"p/".repeat(513), UnsafePath),
            ]),
        ]
        .concat(),
        Grammar::Text => [
            missing,
            c(&[
                ("a\u{1}b", BadText),
                ("tab\there", BadText),
                ("a\u{202E}b", BadText),
                ("zero\u{200B}width", BadText),
                (&"p".repeat(4097), OutOfRange(Bound::Text)),
            ]),
        ]
        .concat(),
        Grammar::TaskName => [
            missing,
            c(&[
                ("a\u{202E}b", BadText),
                ("bell\u{7}", BadText),
                (&"t".repeat(257), OutOfRange(Bound::TaskName)),
            ]),
        ]
        .concat(),
        Grammar::Secret => [missing, c(&[("bell\u{7}", BadText)])].concat(),
        Grammar::NewPassword => [
            missing,
            c(&[
                ("has space", BadPassword),
                (&"x".repeat(33), BadPassword),
                ("é", BadPassword),
                ("1025", SpecialPassword),
                ("0315", SpecialPassword),
            ]),
        ]
        .concat(),
        Grammar::ParamName => [
            missing,
            c(&[
                ("a b", Malformed),
                ("a:b", Malformed),
                (&"p".repeat(65), Malformed),
            ]),
        ]
        .concat(),
        Grammar::SetParam => [
            missing,
            c(&[
                ("noval", Malformed),
                ("name:", Missing),
                (":v", Malformed),
                ("a b:1", Malformed),
                ("takeoff_alt:2\u{202E}", BadText),
            ]),
        ]
        .concat(),
        Grammar::Setpoint => [
            missing,
            c(&[
                ("1:2:3", Malformed),
                ("1:2:3:4:5", Malformed),
                ("nan:0:0:0", NotANumber),
                ("0:0:0:inf", NotANumber),
                ("1,2,3,4", NotANumber),
                ("1:2::4", Missing),
                ("+1:0:-3:0", NotANumber),
                ("1: 2:-3:0", NotANumber),
                ("1:2 :-3:0", NotANumber),
                ("1:2:-3: 0", NotANumber),
                ("3:0:0:0", AtOrBelowGround),
                ("1:2:3:4", AtOrBelowGround),
                ("0:0:-0:0", AtOrBelowGround),
                ("0:0:-1e-50:0", AtOrBelowGround),
                ("0:0:1e-50:0", AtOrBelowGround),
            ]),
        ]
        .concat(),
        Grammar::Point => [
            missing,
            c(&[
                ("1:2", Malformed),
                ("1:2:inf", NotANumber),
                ("1:2:1e40", OutOfRange(Float)),
                ("1:2:3:4", Malformed),
                ("+1:0:0", NotANumber),
            ]),
        ]
        .concat(),
        Grammar::Pose => [
            missing,
            c(&[
                ("1:2:3:4", NotANumber),
                ("1,2,3", Malformed),
                ("1,2,3,nan", NotANumber),
                ("1,2,3,+4", NotANumber),
                ("1, 2,3,4", NotANumber),
            ]),
        ]
        .concat(),
        Grammar::Zyhk => [
            missing,
            c(&[
                ("1,,2", Missing),
                (&vec!["1"; 33].join(","), TooMany),
                ("1 0,0", Malformed),
                ("nan", NotANumber),
                ("1 0,0,x", NotANumber),
                ("1 0,0,0 9", NotANumber),
                ("+1", NotANumber),
                ("1, 2", Malformed),
                ("1 +0,0,0", NotANumber),
            ]),
        ]
        .concat(),
        Grammar::Mission => [
            missing,
            c(&[
                ("1001", Malformed),
                ("x:{}", NotANumber),
                (r#"1:{"a":}"#, BadJson),
                ("1:{", BadJson),
                ("1:[1,]", BadJson),
                (r#"1:{"a":1}}"#, BadJson),
                (r#"1:["\x"]"#, BadJson),
                ("1:[01]", BadJson),
                ("1:[nan]", BadJson),
                (&format!("1:{}{}", "[".repeat(65), "]".repeat(65)), BadJson),
                ("1:../x", UnsafePath),
                ("1:", UnsafePath),
                ("+7:[]", NotANumber),
                (" 7:[]", NotANumber),
                ("7 :[]", NotANumber),
                ("1:.hidden.json", UnsafePath),
            ]),
        ]
        .concat(),
        Grammar::MwExec => [
            missing,
            c(&[
                ("1001:", Missing),
                ("1001:1,,2", Missing),
                (&format!("1:{}", vec!["9"; 65].join(",")), TooMany),
                ("1001:a", NotANumber),
                ("1001", Malformed),
                ("1001:1;2", NotANumber),
                ("+1001:1", NotANumber),
                ("1001:+1", NotANumber),
                ("1001:1, 2", NotANumber),
            ]),
        ]
        .concat(),
        Grammar::Ai1Mission => [
            missing,
            c(&[
                ("t k:a", Malformed),
                ("t:../a", UnsafePath),
                ("t:.a", UnsafePath),
                ("t", Malformed),
                (":a", Malformed),
            ]),
        ]
        .concat(),
        Grammar::Override => c(&[
            ("Failsafe", Malformed),
            ("failsafe now", Malformed),
            ("1", Malformed),
            (" failsafe", Malformed),
        ]),
    }
}

#[test]
fn every_command_accepts_its_valid_forms() {
    for spec in &TABLE {
        for args in valid_args(spec.grammar) {
            let f = frame(spec.name(), &args);
            let cmd = parse(&f).unwrap_or_else(|e| panic!("{f:?} should parse: {e:?}"));
            assert_eq!(cmd.id(), spec.id);
            assert_eq!(cmd.args().grammar(), spec.grammar);
        }
    }
}

#[test]
fn every_command_refuses_its_invalid_forms_with_a_typed_reason() {
    for spec in &TABLE {
        for (args, why) in invalid(spec.grammar) {
            let f = frame(spec.name(), &args);
            assert_eq!(parse(&f), Err(ParseError::InvalidArgs(spec.id, why)), "{f:?}");
        }
    }
}

#[test]
fn invalid_arguments_get_ret_minus_2_and_the_usage_line_or_their_reason() {
    let mut s = server(Some("pw"));
    let mut admin = Session::new();
    assert_eq!(send(&mut s, &mut admin, "login 1025").ret(), 0);
    for spec in &TABLE {
        for (args, why) in invalid(spec.grammar) {
            let r = send(&mut s, &mut admin, &frame(spec.name(), &args));
            assert_eq!(r.ret(), -2, "{}", spec.name());
            assert_eq!(r.cmd(), i64::from(u8::from(spec.id)));
            let msg = match why.reason() {
                Some(reason) => format!("Invalid arguments: {reason}"),
                None => format!("Invalid arguments, usage: {}", spec.usage),
            };
            assert_eq!(r.msg(), msg);
        }
    }
    assert!(
        s.backend().executed.is_empty(),
        "nothing invalid reached the vehicle"
    );
}

#[test]
fn spec_examples_parse_to_their_typed_values() {
    let c = parse("set_sp_ned 1.0:2.0:-3.0:0.5").unwrap();
    let Args::Setpoint(p) = c.args() else {
        panic!("{c:?}")
    };
    assert_eq!((p.x, p.y, p.z, p.yaw), (1.0, 2.0, -3.0, 0.5));

    let c = parse("test_wp 10.0:5.0:-2.0").unwrap();
    let Args::Point(p) = c.args() else { panic!("{c:?}") };
    assert_eq!((p.x, p.y, p.z), (10.0, 5.0, -2.0));

    let c = parse("zyhk 1.5,2.0,2.5").unwrap();
    let Args::Zyhk { heights, land } = c.args() else {
        panic!("{c:?}")
    };
    assert_eq!((heights.as_slice(), land), (&[1.5, 2.0, 2.5][..], &None));

    let c = parse("zyhk 3 1,-2,0.5").unwrap();
    let Args::Zyhk { land: Some(l), .. } = c.args() else {
        panic!("{c:?}")
    };
    assert_eq!((l.x, l.y, l.yaw), (1.0, -2.0, 0.5));

    let c = parse("mw_exec 1001:1,2,3,5").unwrap();
    let Args::MwExec { ext_id, wp_ids } = c.args() else {
        panic!("{c:?}")
    };
    assert_eq!((*ext_id, wp_ids.as_slice()), (1001, &[1, 2, 3, 5][..]));

    let json = r#"{"waypoints":[{"x":1,"y":2,"z":-3,"yaw":0}]}"#;
    let f = format!("mission 1001:{json}");
    let c = parse(&f).unwrap();
    assert_eq!(
        c.args(),
        &Args::Mission {
            ext_id: 1001,
            payload: Payload::Json(json)
        }
    );

    let c = parse("set_param a:b:c").unwrap();
    assert_eq!(
        c.args(),
        &Args::SetParam {
            name: "a",
            value: "b:c"
        },
        "split at the first colon"
    );

    let c = parse("plan fly the east field then  come home").unwrap();
    assert_eq!(c.args(), &Args::Text("fly the east field then  come home"));
}

#[test]
fn trailing_spaces_and_line_ends_are_ignored_but_inner_spacing_is_kept() {
    assert_eq!(parse("takeoff \r\n").unwrap().id(), CommandId::Takeoff);
    assert_eq!(parse("showmsg 5  \n").unwrap().args(), &Args::OptCount(Some(5)));
    assert_eq!(
        parse("showmsg  5"),
        Err(ParseError::InvalidArgs(CommandId::Showmsg, ArgError::NotANumber)),
        "exactly one space separates name and arguments"
    );
    assert_eq!(
        parse("showmsg "),
        parse("showmsg"),
        "a trailing space is no argument"
    );
}

#[test]
fn empty_and_blank_frames_are_empty_commands() {
    let mut s = server(None);
    let mut sess = Session::new();
    for f in ["", " ", "\r\n", "   \n"] {
        assert_eq!(parse(f), Err(ParseError::Empty));
        let r = send(&mut s, &mut sess, f);
        assert_eq!((r.ret(), r.cmd(), r.msg()), (-2, 0, "Empty command"), "{f:?}");
    }
}

#[test]
fn unknown_commands_echo_their_name_cut_to_32_bytes_at_a_char_boundary() {
    let mut s = server(None);
    let mut sess = Session::new();
    let cases = [
        ("fly_to_moon 1 2", "fly_to_moon".to_string()),
        (&*"x".repeat(40), "x".repeat(32)),
        (&*format!("{}é", "a".repeat(31)), "a".repeat(31)),
        (&*"é".repeat(20), "é".repeat(16)),
        ("q\"uo\\te\u{1}", "q\"uo\\te\u{1}".to_string()),
        ("STATE", "STATE".to_string()),
        ("\tstate", "\tstate".to_string()),
    ];
    for (f, shown) in cases {
        let r = send(&mut s, &mut sess, f);
        assert_eq!((r.ret(), r.cmd()), (-2, 0), "{f:?}");
        assert_eq!(r.msg(), format!("Unsupported command: {shown}"), "{f:?}");
    }
}

#[test]
fn a_frame_with_a_leading_space_has_an_empty_name() {
    assert_eq!(parse(" state"), Err(ParseError::Unknown("")));
}

#[test]
fn every_grammar_in_the_table_has_valid_and_invalid_cases() {
    for spec in &TABLE {
        assert!(!valid_args(spec.grammar).is_empty(), "{:?}", spec.grammar);
        assert!(!invalid(spec.grammar).is_empty(), "{:?}", spec.grammar);
    }
}

#[test]
fn a_setpoint_at_or_below_the_ground_is_refused_with_its_reason() {
    let mut s = server(None);
    let mut sess = Session::new();
    for frame in [
        "set_sp_ned 3:0:0:0",
        "set_sp_ned 0:0:0.5:0",
        "set_sp_ned 0:0:-0:0",
    ] {
        let r = send(&mut s, &mut sess, frame);
        assert_eq!((r.ret(), r.cmd()), (-2, 23), "{frame}");
        assert_eq!(
            r.msg(),
            "Invalid arguments: setpoint at or below the ground (z >= 0; up is negative z): use land to descend"
        );
    }
    assert!(s.backend().executed.is_empty(), "none reached the vehicle");
    assert_eq!(send(&mut s, &mut sess, "set_sp_ned 3:0:-0.5:0").ret(), 0);
}

#[test]
fn hand_built_commands_obey_the_same_number_and_ground_rules() {
    use lluav_core::{Command, Number, Pose};
    let ground = Pose {
        x: 1.0,
        y: 0.0,
        z: 0.0,
        yaw: 0.0,
    };
    assert_eq!(
        Command::new(CommandId::SetSpNed, Args::Setpoint(ground)),
        Err(ArgError::AtOrBelowGround)
    );
    let up = Pose { z: -1.0, ..ground };
    assert!(Command::new(CommandId::SetSpNed, Args::Setpoint(up)).is_ok());
    assert_eq!(
        Command::new(CommandId::ApronVol, Args::Amount(Number::from(-0.5))),
        Err(ArgError::OutOfRange(Bound::NonNegative))
    );
    assert_eq!(
        Command::new(CommandId::Ara8Pitch, Args::Angle(90.5)),
        Err(ArgError::OutOfRange(Bound::Angle))
    );
    assert_eq!(
        Command::new(CommandId::SetTaskname, Args::TaskName("a\u{202E}b")),
        Err(ArgError::BadText)
    );
    assert_eq!(
        Command::new(CommandId::Passwd, Args::NewPassword("1025")),
        Err(ArgError::SpecialPassword)
    );
    // A number parsed from a frame keeps its text, so that it encodes as
    // sent and a backend compares its range with what the client meant.
    let c = parse("apron_vol 60.000001").unwrap();
    assert_eq!(c.to_string(), "apron_vol 60.000001");
    let Args::Amount(v) = c.args() else {
        panic!("{c:?}")
    };
    assert!(v.above(60.0) && v.value() == 60.0);
    assert_ne!(*v, Number::from(60.0));
}

/// Every code point inside a name: refused exactly when it is a separator,
/// or a Unicode control (Cc) or format (Cf) character, by the Unicode
/// tables of the `regex` crate.
#[test]
fn names_refuse_exactly_separators_and_unicode_control_and_format_characters() {
    let invisible = regex::Regex::new(r"^[\p{Cc}\p{Cf}]$").unwrap();
    let mut refused = 0;
    for c in (0..=0x10_FFFF).filter_map(char::from_u32) {
        let frame = format!("rm_map a{c}b");
        let expected = c == '/' || c == '\\' || invisible.is_match(c.encode_utf8(&mut [0; 4]));
        assert_eq!(parse(&frame).is_err(), expected, "U+{:04X}", u32::from(c));
        refused += usize::from(expected);
    }
    assert!(refused > 65 + 150, "{refused}");
}

#[test]
fn length_refusals_name_the_limits_the_grammar_enforces() {
    use lluav_core::parse::{MAX_TASK_NAME_LEN, MAX_TEXT_LEN};
    assert!(Bound::Text.reason().contains(&format!(" {MAX_TEXT_LEN} bytes")));
    assert!(
        Bound::TaskName
            .reason()
            .contains(&format!(" {MAX_TASK_NAME_LEN} bytes"))
    );
    for bound in [
        Bound::Angle,
        Bound::NonNegative,
        Bound::Pwm,
        Bound::Integer,
        Bound::Float,
        Bound::Text,
        Bound::TaskName,
    ] {
        assert!(!bound.reason().is_empty(), "{bound:?}");
        assert_eq!(ArgError::OutOfRange(bound).reason(), Some(bound.reason()));
    }
}
