//! The command table against the contract: the specification's commands and
//! DESIGN.md's ids, gate lists and flight-authority classes.

use lluav_core::{Class, CommandId, Effect, Section, TABLE, table};

/// DESIGN.md, "Ids": lluav's own commands, appended after the spec's 99.
const EXTENSIONS: &[(&str, u8)] = &[("control", 100), ("control_take", 101), ("control_release", 102)];

/// DESIGN.md, "Sessions and gates": runOnArm=false.
const NOT_WHILE_ARMED: &[&str] = &[
    "takeoff",
    "sleep",
    "autosleep_enable",
    "relocate_pos",
    "savemap",
    "set_maplocate",
    "set_mappath",
    "rm_map",
    "siyi_reboot",
    "siyi_format",
    "siyi_init",
    "siyi_downvideo",
    "set_param",
    "reset_param",
    "save_param",
    "apron_vol",
    "apron_amp",
    "reboot_node",
    "reboot_ap",
    "reboot_system",
    "poweroff_system",
    "prepare_poweroff",
    "reboot_dlo",
    "restart_dlo",
    "kill_livox",
    "lidaronoff",
    "cv_test",
    "preflight_check",
    "preflight_enable",
    "clear_bags",
    "clear_images",
    "rm_imagedir",
    "bms_setpower",
    "bms_setcharge",
];

/// DESIGN.md, "Sessions and gates": runInLock=false.
const NOT_IN_LOCK: &[&str] = &[
    "set_param",
    "reset_param",
    "save_param",
    "passwd",
    "savemap",
    "set_maplocate",
    "set_mappath",
    "rm_map",
    "rm_imagedir",
    "clear_bags",
    "clear_images",
    "siyi_reboot",
    "siyi_format",
    "siyi_init",
    "apron_vol",
    "apron_amp",
    "reboot_node",
    "reboot_ap",
    "reboot_system",
    "poweroff_system",
    "prepare_poweroff",
    "reboot_dlo",
    "restart_dlo",
    "kill_livox",
    "lidaronoff",
    "preflight_enable",
    "autosleep_enable",
    "unlock_plan",
    "cv_test",
    "bms_setpower",
    "bms_setcharge",
];

/// The commands that must reach the vehicle whatever the gates.
pub const SAFETY: &[&str] = &["land", "rtl", "mrtl", "tether_land", "disarm", "set_sp_ned"];

#[test]
fn table_holds_login_the_98_commands_of_the_reference_and_the_extensions_in_id_order() {
    assert_eq!(TABLE.len(), 99 + EXTENSIONS.len());
    for (i, spec) in TABLE.iter().enumerate() {
        assert_eq!(usize::from(u8::from(spec.id)), i + 1, "{}", spec.name());
        assert_eq!(CommandId::from_u8(u8::from(spec.id)), Some(spec.id));
        assert_eq!(table::lookup(spec.name()).map(|s| s.id), Some(spec.id));
        assert_eq!(CommandId::from_name(spec.name()), Some(spec.id));
        assert!(
            spec.usage.starts_with(spec.name()),
            "usage names the command: {}",
            spec.usage
        );
        assert!(!spec.summary().is_empty());
    }
    assert_eq!(CommandId::from_u8(0), None, "0 means unknown");
    assert_eq!(CommandId::from_u8(103), None);
    for (name, id) in EXTENSIONS {
        assert_eq!(CommandId::from_name(name).map(u8::from), Some(*id), "{name}");
        assert_eq!(
            CommandId::from_name(name).map(CommandId::section),
            Some(Section::Control)
        );
    }
}

#[test]
fn ids_follow_the_first_appearance_in_the_spec() {
    let expect = [
        ("login", 1),
        ("state", 2),
        ("param", 3),
        ("get_param", 4),
        ("showmsg", 17),
        ("takeoff", 18),
        ("set_sp_ned", 23),
        ("mission", 31),
        ("siyi_format", 52),
        ("set_param", 63),
        ("passwd", 66),
        ("help", 97),
        ("admin_unlock", 99),
    ];
    for (name, id) in expect {
        assert_eq!(CommandId::from_name(name).map(u8::from), Some(id), "{name}");
    }
}

/// The spec's Command Reference, as (heading, command name) in reading
/// order: every table row's first cell that looks like a command name.
fn reference_rows() -> Vec<(&'static str, &'static str)> {
    let spec = include_str!("../../docs/lluav-websocket-protocol.md");
    let reference = spec
        .split("## Command Reference")
        .nth(1)
        .expect("the spec has a Command Reference");
    let mut heading = "";
    let mut rows = Vec::new();
    for line in reference.lines() {
        if let Some(h) = line.strip_prefix("### ") {
            heading = h.trim();
        }
        let Some(rest) = line.strip_prefix("| ") else {
            continue;
        };
        let name = rest.split(' ').next().unwrap_or("");
        let is_command = !name.is_empty()
            && name
                .bytes()
                .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_')
            && !["ret", "cmd", "ts"].contains(&name);
        if is_command {
            rows.push((heading, name));
        }
    }
    rows
}

/// Each command of the reference once, where it first appears.
fn first_appearances() -> Vec<(&'static str, &'static str)> {
    let mut seen: Vec<(&str, &str)> = vec![("Authentication", "login")];
    for (heading, name) in reference_rows() {
        if !seen.iter().any(|(_, n)| *n == name) {
            seen.push((heading, name));
        }
    }
    seen
}

#[test]
fn every_command_of_the_spec_reference_is_in_the_table() {
    let names: Vec<&str> = first_appearances().into_iter().map(|(_, n)| n).collect();
    let table: Vec<&str> = TABLE.iter().map(|s| s.name()).take(99).collect();
    assert_eq!(
        table, names,
        "the table lists the spec's commands in the spec's order"
    );
}

#[test]
fn every_command_stands_in_the_section_where_the_spec_first_lists_it() {
    let section = |h: &str| match h {
        "Authentication" => Section::Authentication,
        "State & Telemetry" => Section::State,
        "Flight Control" => Section::Flight,
        "Mission Management" => Section::Mission,
        "Map Management" => Section::Map,
        "Camera & Recording" => Section::Camera,
        "LED Control" => Section::Led,
        "Parameter Management" => Section::Param,
        "Apron (Charging Pad)" => Section::Apron,
        "System Management" => Section::System,
        "Lidar & Perception" => Section::Lidar,
        "Other" => Section::Other,
        other => panic!("a heading the table has no section for: {other}"),
    };
    let first = first_appearances();
    assert_eq!(first.len() + EXTENSIONS.len(), TABLE.len());
    for (heading, name) in first {
        let id = CommandId::from_name(name).expect("a known name");
        assert_eq!(id.section(), section(heading), "{name}");
    }
}

#[test]
fn lookup_is_exact_and_case_sensitive() {
    for name in ["", "STATE", "state ", " state", "stat", "states", "land\0"] {
        assert_eq!(table::lookup(name), None, "{name:?}");
    }
}

#[test]
fn gate_flags_match_design() {
    for spec in &TABLE {
        assert_eq!(
            spec.flags.run_on_arm(),
            !NOT_WHILE_ARMED.contains(&spec.name()),
            "runOnArm of {}",
            spec.name()
        );
        assert_eq!(
            spec.flags.run_in_lock(),
            !NOT_IN_LOCK.contains(&spec.name()),
            "runInLock of {}",
            spec.name()
        );
        assert_eq!(
            spec.flags.admin_only(),
            ["admin_lock", "admin_unlock"].contains(&spec.name()),
            "admin-only of {}",
            spec.name()
        );
    }
    for name in NOT_WHILE_ARMED.iter().chain(NOT_IN_LOCK) {
        assert!(
            table::lookup(name).is_some(),
            "DESIGN names an unknown command {name}"
        );
    }
}

#[test]
fn safety_commands_are_never_gated_by_arm_or_lock() {
    for name in SAFETY {
        let spec = table::lookup(name).expect("safety command exists");
        assert!(
            spec.flags.run_on_arm() && spec.flags.run_in_lock() && !spec.flags.admin_only(),
            "{name}"
        );
    }
}

/// DESIGN.md, "Flight authority": each command's class and effect.
#[test]
fn classes_and_effects_match_design() {
    let motion = ["takeoff", "set_sp_ned", "zyhk", "mw_exec"];
    let conservative = ["land", "tether_land", "disarm"];
    let returns = ["rtl", "mrtl"];
    let session = ["login", "control", "control_take", "control_release"];
    for spec in &TABLE {
        let class = match spec.name() {
            n if motion.contains(&n) => Class::Motion,
            n if conservative.contains(&n) => Class::Conservative,
            n if returns.contains(&n) => Class::Return,
            "abort_report" => Class::StopsMission,
            _ => Class::Neutral,
        };
        assert_eq!(spec.class, class, "class of {}", spec.name());
        if session.contains(&spec.name()) {
            assert_eq!(spec.effect, Effect::Session, "{}", spec.name());
        }
        // A command that changes nothing moves nothing either.
        if spec.effect == Effect::Read {
            assert_eq!(spec.class, Class::Neutral, "{}", spec.name());
        }
    }
    for name in [
        "state",
        "param",
        "get_param",
        "help",
        "mw_list",
        "showmsg",
        "test_wp",
    ] {
        assert_eq!(
            table::lookup(name).map(|s| s.effect),
            Some(Effect::Read),
            "{name}"
        );
    }
    for name in [
        "takeoff",
        "set_param",
        "passwd",
        "admin_lock",
        "mission",
        "capture",
    ] {
        assert_eq!(
            table::lookup(name).map(|s| s.effect),
            Some(Effect::Vehicle),
            "{name}"
        );
    }
}

#[test]
fn the_fuzz_dictionary_lists_exactly_the_table() {
    let dict = include_str!("../../fuzz/lluav.dict");
    let names: Vec<&str> = dict
        .lines()
        .take_while(|l| !l.starts_with("# Separators"))
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.trim_matches('"'))
        .collect();
    let table: Vec<&str> = TABLE.iter().map(|s| s.name()).collect();
    assert_eq!(names, table);
}
