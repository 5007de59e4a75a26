//! The gate matrix and the login rules (DESIGN.md, "Sessions and gates").

mod common;

use common::*;
use lluav_core::{CommandId, Session, Spec, TABLE};

#[derive(Clone, Copy, Debug, PartialEq)]
enum Who {
    LoggedOut,
    User,
    Admin,
}

/// What DESIGN.md's gate order says must happen, from the table's flags.
fn expected(spec: &Spec, who: Who, armed: bool, locked: bool) -> Result<(), &'static str> {
    if who == Who::LoggedOut && spec.id != CommandId::Login {
        return Err("Login first!");
    }
    if spec.flags.admin_only() && who != Who::Admin {
        return Err("Admin only!");
    }
    if !spec.flags.run_on_arm() && armed {
        return Err("Not allow when vehicle is ARMED!");
    }
    if !spec.flags.run_in_lock() && locked && who != Who::Admin {
        return Err("CMD not permitted to run in LOCK mode!");
    }
    Ok(())
}

/// Runs `spec` with its first valid argument form in the given situation.
fn run(spec: &Spec, who: Who, armed: bool, locked: bool) -> (Seen, Vec<CommandId>) {
    let mut s = server(Some("pw"));
    if locked {
        let mut op = Session::new();
        assert_eq!(send(&mut s, &mut op, "login 1025").ret(), 0);
        assert_eq!(send(&mut s, &mut op, "admin_lock").ret(), 0);
    }
    let mut sess = Session::new();
    match who {
        Who::LoggedOut => {}
        Who::User => assert_eq!(send(&mut s, &mut sess, "login pw").ret(), 0),
        Who::Admin => assert_eq!(send(&mut s, &mut sess, "login 1025").ret(), 0),
    }
    s.backend_mut().armed = armed;
    let args = match spec.id {
        CommandId::Login => Some("pw".to_string()),
        _ => valid_args(spec.grammar).remove(0),
    };
    let seen = send(&mut s, &mut sess, &frame(spec.name(), &args));
    (seen, s.backend().executed.clone())
}

/// Commands the core answers itself; everything else goes to the backend.
fn core_owned(id: CommandId) -> bool {
    matches!(
        id,
        CommandId::Login
            | CommandId::Help
            | CommandId::AdminLock
            | CommandId::AdminUnlock
            | CommandId::Passwd
            | CommandId::Control
            | CommandId::ControlTake
            | CommandId::ControlRelease
    )
}

#[test]
fn the_gate_matrix_holds_for_every_command() {
    let mut checked = 0;
    for spec in &TABLE {
        for who in [Who::LoggedOut, Who::User, Who::Admin] {
            for armed in [false, true] {
                for locked in [false, true] {
                    let (seen, executed) = run(spec, who, armed, locked);
                    let case = format!("{} as {who:?}, armed={armed}, locked={locked}", spec.name());
                    assert_eq!(seen.cmd(), i64::from(u8::from(spec.id)), "{case}");
                    match expected(spec, who, armed, locked) {
                        Err(msg) => {
                            assert_eq!((seen.ret(), seen.msg()), (-1, msg), "{case}");
                            assert!(executed.is_empty(), "{case}: refused yet executed");
                        }
                        // Past every gate, but nobody holds control.
                        Ok(()) if spec.id == CommandId::ControlRelease => {
                            assert_eq!(
                                (seen.ret(), seen.msg()),
                                (-1, "This session is not in control"),
                                "{case}"
                            );
                        }
                        Ok(()) => {
                            assert_eq!(seen.ret(), 0, "{case}: {seen:?}");
                            let want = if core_owned(spec.id) {
                                vec![]
                            } else {
                                vec![spec.id]
                            };
                            assert_eq!(executed, want, "{case}");
                        }
                    }
                    checked += 1;
                }
            }
        }
    }
    assert_eq!(checked, TABLE.len() * 3 * 2 * 2);
}

#[test]
fn safety_commands_run_for_a_plain_user_while_armed_and_locked() {
    for name in ["land", "rtl", "mrtl", "tether_land", "disarm", "set_sp_ned"] {
        let spec = lluav_core::table::lookup(name).unwrap();
        let (seen, executed) = run(spec, Who::User, true, true);
        assert_eq!(seen.ret(), 0, "{name}: {seen:?}");
        assert_eq!(executed, vec![spec.id]);
    }
}

#[test]
fn armed_vehicle_refuses_reboot_and_takeoff_but_not_land() {
    let mut s = server(None);
    let mut sess = Session::new();
    s.backend_mut().armed = true;
    for f in ["reboot_system", "takeoff", "set_param a:1"] {
        assert_eq!(
            send(&mut s, &mut sess, f).msg(),
            "Not allow when vehicle is ARMED!",
            "{f}"
        );
    }
    assert_eq!(send(&mut s, &mut sess, "land").ret(), 0);
}

#[test]
fn without_a_password_every_command_runs_without_login() {
    let mut s = server(None);
    let mut sess = Session::new();
    assert_eq!(send(&mut s, &mut sess, "state").ret(), 0);
    assert_eq!(send(&mut s, &mut sess, "admin_lock").msg(), "Admin only!");
    assert_eq!(send(&mut s, &mut sess, "login 1025").json()["admin"], true);
    assert_eq!(send(&mut s, &mut sess, "admin_lock").ret(), 0);
    assert_eq!(send(&mut s, &mut sess, "login nope").msg(), "Wrong password!");
}

#[test]
fn before_login_unknown_names_and_bad_arguments_get_login_first() {
    let mut s = server(Some("pw"));
    let mut sess = Session::new();
    for (f, cmd) in [("bogus", 0), ("", 0), ("set_sp_ned nan", 23), ("takeoff", 18)] {
        let r = send(&mut s, &mut sess, f);
        assert_eq!((r.ret(), r.cmd(), r.msg()), (-1, cmd, "Login first!"), "{f:?}");
    }
    let r = send(&mut s, &mut sess, "login");
    assert_eq!(
        (r.ret(), r.msg()),
        (-2, "Invalid arguments, usage: login <password>")
    );
}

#[test]
fn login_values_grant_user_admin_or_log_out() {
    let mut s = server(Some("pw"));
    let mut sess = Session::new();
    let r = send(&mut s, &mut sess, "login pw");
    assert_eq!(
        (r.ret(), r.cmd(), &r.json()["admin"]),
        (0, 1, &serde_json::json!(false))
    );
    assert_eq!(send(&mut s, &mut sess, "admin_lock").msg(), "Admin only!");
    let r = send(&mut s, &mut sess, "login 1025");
    assert_eq!((r.ret(), &r.json()["admin"]), (0, &serde_json::json!(true)));
    let r = send(&mut s, &mut sess, "login 0315");
    assert_eq!((r.ret(), &r.json()["logged_in"]), (0, &serde_json::json!(false)));
    assert_eq!(send(&mut s, &mut sess, "state").msg(), "Login first!");
}

#[test]
fn the_fifth_wrong_password_in_a_row_is_answered_then_closed_with_1008() {
    let mut s = server(Some("pw"));
    let mut sess = Session::new();
    for _ in 0..4 {
        let r = send(&mut s, &mut sess, "login guess");
        assert!(matches!(r, Seen::Reply(_)));
        assert_eq!((r.ret(), r.cmd(), r.msg()), (-1, 1, "Wrong password!"));
    }
    let r = send(&mut s, &mut sess, "login guess");
    assert!(matches!(r, Seen::ReplyThenClose(_, 1008)), "{r:?}");
    assert_eq!(r.msg(), "Wrong password!");
}

#[test]
fn a_successful_login_resets_the_wrong_password_count() {
    let mut s = server(Some("pw"));
    let mut sess = Session::new();
    for round in 0..3 {
        for _ in 0..4 {
            assert!(
                matches!(send(&mut s, &mut sess, "login guess"), Seen::Reply(_)),
                "round {round}"
            );
        }
        assert_eq!(send(&mut s, &mut sess, "login pw").ret(), 0);
    }
}

#[test]
fn lock_mode_is_vehicle_wide_and_admins_skip_it() {
    let mut s = server(Some("pw"));
    let (mut op, mut user) = (Session::new(), Session::new());
    send(&mut s, &mut op, "login 1025");
    send(&mut s, &mut user, "login pw");
    assert_eq!(send(&mut s, &mut op, "admin_lock").json()["lock_mode"], true);
    assert_eq!(send(&mut s, &mut op, "admin_lock").ret(), 0, "idempotent");
    assert_eq!(
        send(&mut s, &mut user, "reboot_node").msg(),
        "CMD not permitted to run in LOCK mode!"
    );
    assert_eq!(
        send(&mut s, &mut user, "state").json()["state"]["lock_mode"],
        true
    );
    assert_eq!(send(&mut s, &mut op, "reboot_node").ret(), 0);
    assert_eq!(send(&mut s, &mut op, "admin_unlock").json()["lock_mode"], false);
    assert_eq!(send(&mut s, &mut op, "admin_unlock").ret(), 0, "idempotent");
    assert_eq!(send(&mut s, &mut user, "reboot_node").ret(), 0);
}

#[test]
fn lock_mode_is_handed_to_the_backend_before_it_takes_effect() {
    let mut s = server(Some("pw"));
    let mut op = Session::new();
    send(&mut s, &mut op, "login 1025");
    send(&mut s, &mut op, "admin_lock");
    assert_eq!(s.backend().saved_lock_mode, Some(true));
    s.backend_mut().lock_save_fails = Some(lluav_core::Failure::system("save lock mode: disk full"));
    let r = send(&mut s, &mut op, "admin_unlock");
    assert_eq!((r.ret(), r.msg()), (-3, "save lock mode: disk full"));
    assert!(s.auth().lock_mode(), "a lock that was not saved is not lifted");
    assert_eq!(s.backend().saved_lock_mode, Some(true));
    assert_eq!(send(&mut s, &mut op, "admin_unlock").json()["lock_mode"], false);
    assert_eq!(s.backend().saved_lock_mode, Some(false));
}

#[test]
fn passwd_changes_the_vehicle_password_for_every_new_session() {
    let mut s = server(Some("pw"));
    let mut sess = Session::new();
    send(&mut s, &mut sess, "login pw");
    assert_eq!(send(&mut s, &mut sess, "passwd n3w-secret").ret(), 0);
    assert_eq!(s.backend().saved_password.as_deref(), Some("n3w-secret"));
    assert_eq!(s.auth().password(), Some("n3w-secret"));
    let mut other = Session::new();
    assert_eq!(send(&mut s, &mut other, "login pw").msg(), "Wrong password!");
    assert_eq!(send(&mut s, &mut other, "login n3w-secret").ret(), 0);
}

#[test]
fn passwd_refuses_the_special_values_and_bad_passwords_saying_why() {
    let mut s = server(Some("pw"));
    let mut sess = Session::new();
    send(&mut s, &mut sess, "login pw");
    let special = "Invalid arguments: the admin and logout values cannot be passwords";
    let rules = "Invalid arguments, usage: passwd new_password";
    for (f, msg) in [
        ("passwd 1025", special),
        ("passwd 0315", special),
        ("passwd two words", rules),
        ("passwd", "Invalid arguments, usage: passwd new_password"),
    ] {
        let r = send(&mut s, &mut sess, f);
        assert_eq!((r.ret(), r.msg()), (-2, msg), "{f}");
    }
    assert_eq!(s.auth().password(), Some("pw"));
    assert_eq!(s.backend().saved_password, None, "nothing persisted");
}

#[test]
fn passwd_refuses_configured_special_values_without_saying_which() {
    let auth = lluav_core::Auth::with_specials(Some("pw"), "root!", "bye!").unwrap();
    let mut s = lluav_core::Server::new(MockVehicle::default(), clock as fn() -> i64, auth);
    let mut sess = Session::new();
    send(&mut s, &mut sess, "login pw");
    for f in ["passwd root!", "passwd bye!"] {
        let r = send(&mut s, &mut sess, f);
        assert_eq!(
            (r.ret(), r.msg()),
            (
                -2,
                "Invalid arguments: the admin and logout values cannot be passwords"
            ),
            "{f}"
        );
    }
    assert_eq!(s.auth().password(), Some("pw"));
}

#[test]
fn setting_a_password_on_an_open_vehicle_keeps_the_setter_logged_in() {
    let mut s = server(None);
    let (mut setter, mut other) = (Session::new(), Session::new());
    assert_eq!(send(&mut s, &mut setter, "passwd fresh").ret(), 0);
    assert_eq!(send(&mut s, &mut setter, "state").ret(), 0);
    assert_eq!(send(&mut s, &mut other, "state").msg(), "Login first!");
}

#[test]
fn special_login_values_are_configurable() {
    let auth = lluav_core::Auth::with_specials(Some("pw"), "root!", "bye!").unwrap();
    let mut s = lluav_core::Server::new(MockVehicle::default(), clock as fn() -> i64, auth);
    let mut sess = Session::new();
    assert_eq!(send(&mut s, &mut sess, "login 1025").msg(), "Wrong password!");
    assert_eq!(send(&mut s, &mut sess, "login root!").json()["admin"], true);
    assert_eq!(send(&mut s, &mut sess, "login bye!").json()["logged_in"], false);
    assert!(lluav_core::Auth::with_specials(Some("same"), "same", "x").is_err());
    assert!(lluav_core::Auth::with_specials(None, "same", "same").is_err());
    assert!(lluav_core::Auth::new(Some("has space")).is_err());
}
