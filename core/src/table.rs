//! The command table: the one place that lists every command.
//!
//! Each row gives a command's stable id, its wire name, its argument
//! [`Grammar`], its gate [`Flags`], its usage line and a one-line summary.
//! Parsing, gating, `help`, the encoder, the clients and the tests all read
//! this table; nothing else in the project lists commands.
//!
//! Ids follow DESIGN.md: `login` is 1, then every command in the order it
//! first appears in the specification's Command Reference. 0 is reserved for
//! "not a known command" and is never a [`CommandId`].

/// The shape of a command's arguments, which decides how they are parsed,
/// validated and encoded. Each grammar has exactly one [`crate::Args`]
/// variant of the same name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Grammar {
    /// No arguments at all.
    None,
    /// Exactly `0` or `1`.
    Flag,
    /// An optional unsigned decimal integer.
    OptCount,
    /// An integer PWM value, 0–65535.
    Pwm,
    /// A finite number ≥ 0.
    Amount,
    /// An optional finite number ≥ 0.
    OptAmount,
    /// A finite angle in degrees, -90..=90.
    Angle,
    /// A single path component (no `/`, `\`, `..`, NUL or control characters).
    Name,
    /// An optional single path component.
    OptName,
    /// A relative path made of single path components joined by `/`.
    Path,
    /// Free text: the rest of the frame, no control or format characters
    /// (Unicode Cc, Cf), at most 4096 bytes.
    Text,
    /// A task name: text as [`Grammar::Text`], at most 256 bytes.
    TaskName,
    /// A login password: the rest of the frame.
    Secret,
    /// A new login password: 1–32 printable ASCII characters, no space.
    NewPassword,
    /// A parameter name: 1–64 of `[A-Za-z0-9_.-]`.
    ParamName,
    /// `name:value`, split at the first colon.
    SetParam,
    /// `x:y:z:yaw`, four finite numbers.
    Setpoint,
    /// `x:y:z`, three finite numbers.
    Point,
    /// `x,y,z,yaw`, four finite numbers.
    Pose,
    /// `h1,h2,... [lx,ly,lyaw]`: heights, then optionally a landing point.
    Zyhk,
    /// `ext_id:path_or_json`, split at the first colon.
    Mission,
    /// `ext_id:id,id,...`, split at the first colon.
    MwExec,
    /// `task_id:mission_file`, split at the first colon.
    Ai1Mission,
    /// Nothing, or the word `failsafe` (`control_take`).
    Override,
}

/// The heading a command stands under in the specification's Command
/// Reference (`login` under "Authentication"). Backends route commands to
/// the subsystem that owns them by section.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Section {
    /// Authentication: `login`.
    Authentication,
    /// State & Telemetry.
    State,
    /// Flight Control.
    Flight,
    /// Mission Management.
    Mission,
    /// Map Management.
    Map,
    /// Camera & Recording.
    Camera,
    /// LED Control.
    Led,
    /// Parameter Management.
    Param,
    /// Apron (Charging Pad).
    Apron,
    /// System Management.
    System,
    /// Lidar & Perception.
    Lidar,
    /// Other.
    Other,
    /// lluav's own extensions, after the specification's commands: who is
    /// in control of the flight (DESIGN.md, "Flight authority").
    Control,
}

/// Gate flags of one command (DESIGN.md, "Sessions and gates"), as bits
/// of one byte: with the row's other one-byte fields the table's rows are
/// 16 bytes, not 20 (408 bytes of a firmware's flash).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Flags(u8);

impl Flags {
    const NOT_ON_ARM: u8 = 1;
    const NOT_IN_LOCK: u8 = 2;
    const ADMIN_ONLY: u8 = 4;

    /// The default: runs armed, runs in lock mode, open to every session.
    const OPEN: Flags = Flags(0);

    /// `runOnArm`: the command may run while the vehicle is armed.
    pub const fn run_on_arm(self) -> bool {
        self.0 & Self::NOT_ON_ARM == 0
    }

    /// `runInLock`: a non-admin session may run it in lock mode.
    pub const fn run_in_lock(self) -> bool {
        self.0 & Self::NOT_IN_LOCK == 0
    }

    /// Only an admin session may run it.
    pub const fn admin_only(self) -> bool {
        self.0 & Self::ADMIN_ONLY != 0
    }

    const fn with(self, bit: u8) -> Flags {
        Flags(self.0 | bit)
    }
}

/// What a command does to the flight, for the failsafe and control gates
/// (DESIGN.md, "Flight authority").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Class {
    /// Gives the vehicle a place to go or sets it moving: only the session
    /// in control (or any session while control is free) may send it, and
    /// never during a failsafe.
    Motion,
    /// Motion while a mission runs, because it stops the mission; neither
    /// otherwise (`abort_report` also closes a report).
    StopsMission,
    /// Brings the vehicle down: open to every logged-in session, passes
    /// control to its sender.
    Conservative,
    /// Conservative, but climbs first to return home (`rtl`, `mrtl`): also
    /// refused while a failsafe lands the vehicle.
    Return,
    /// Neither.
    Neutral,
}

impl Class {
    /// Whether a command of this class steers the vehicle, given whether a
    /// mission is running (asked only for [`Class::StopsMission`]).
    pub fn steers(self, mission_running: impl FnOnce() -> bool) -> bool {
        match self {
            Class::Motion => true,
            Class::StopsMission => mission_running(),
            Class::Conservative | Class::Return | Class::Neutral => false,
        }
    }

    /// Whether it brings the vehicle down or home.
    pub fn conservative(self) -> bool {
        matches!(self, Class::Conservative | Class::Return)
    }
}

/// What running a command changes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Effect {
    /// Nothing: running it twice is running it once.
    Read,
    /// This session only (`login`, `control*`), and nothing that outlives
    /// it.
    Session,
    /// The vehicle or what it keeps.
    Vehicle,
}

/// A command's gate flags, class and effect, as a row's marks build them.
#[derive(Clone, Copy, Debug)]
struct Marks {
    flags: Flags,
    class: Class,
    effect: Effect,
}

impl Marks {
    /// Unmarked: open to every session, neutral, changes the vehicle.
    const NONE: Marks = Marks {
        flags: Flags::OPEN,
        class: Class::Neutral,
        effect: Effect::Vehicle,
    };

    const fn flags(self, flags: Flags) -> Marks {
        Marks { flags, ..self }
    }

    const fn class(self, class: Class) -> Marks {
        Marks { class, ..self }
    }

    const fn effect(self, effect: Effect) -> Marks {
        Marks { effect, ..self }
    }
}

/// Everything the protocol knows about one command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Spec {
    /// The stable id sent as `cmd`.
    pub id: CommandId,
    /// The name's length: the name on the wire is the start of the usage
    /// line ([`Spec::name`]), stored once.
    name_len: u8,
    /// Where the specification lists it.
    pub section: Section,
    /// How the arguments are written.
    pub grammar: Grammar,
    /// Gate flags.
    pub flags: Flags,
    /// What it does to the flight.
    pub class: Class,
    /// What running it changes.
    pub effect: Effect,
    /// The usage line, e.g. `set_sp_ned x:y:z:yaw`.
    pub usage: &'static str,
}

impl Spec {
    /// The name on the wire: the start of the usage line.
    pub const fn name(&self) -> &'static str {
        match self.usage.split_at_checked(self.name_len as usize) {
            Some((name, _)) => name,
            None => self.usage,
        }
    }

    /// Whether its wire name is `name`: bytes, no character boundary to
    /// check (a name is ASCII), as the lookup before every request wants.
    fn is_named(&self, name: &str) -> bool {
        self.usage.as_bytes().get(..usize::from(self.name_len)) == Some(name.as_bytes())
    }

    /// One line saying what the command does (kept out of the table so
    /// that a firmware that never prints it links none of the text).
    pub fn summary(&self) -> &'static str {
        self.id.summary()
    }
}

// A row's marks: `NO_ARM` = runOnArm=false, `NO_LOCK` = runInLock=false,
// `ADMIN` = admin only; `MOTION`, `STOPS_MISSION`, `CONSERVATIVE` = its
// class (`RETURN`: conservative and climbs; else neutral); `READ`, `SESSION` = its effect (else vehicle).
macro_rules! marks {
    () => { Marks::NONE };
    (NO_ARM $($rest:ident)*) => { { let m = marks!($($rest)*); m.flags(m.flags.with(Flags::NOT_ON_ARM)) } };
    (NO_LOCK $($rest:ident)*) => { { let m = marks!($($rest)*); m.flags(m.flags.with(Flags::NOT_IN_LOCK)) } };
    (ADMIN $($rest:ident)*) => { { let m = marks!($($rest)*); m.flags(m.flags.with(Flags::ADMIN_ONLY)) } };
    (MOTION $($rest:ident)*) => { marks!($($rest)*).class(Class::Motion) };
    (STOPS_MISSION $($rest:ident)*) => { marks!($($rest)*).class(Class::StopsMission) };
    (CONSERVATIVE $($rest:ident)*) => { marks!($($rest)*).class(Class::Conservative) };
    (RETURN $($rest:ident)*) => { marks!($($rest)*).class(Class::Return) };
    (READ $($rest:ident)*) => { marks!($($rest)*).effect(Effect::Read) };
    (SESSION $($rest:ident)*) => { marks!($($rest)*).effect(Effect::Session) };
}

macro_rules! command_table {
    ($( $section:ident {
        $( $id:literal $variant:ident $name:literal $grammar:ident [$($flag:ident)*] $usage:literal $summary:literal; )*
    } )*) => {
        /// A known command. The discriminant is the id sent as `cmd`.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
        #[repr(u8)]
        pub enum CommandId {
            $( $( #[doc = $summary] $variant = $id, )* )*
        }

        /// The command table, in id order: `TABLE[id - 1]` describes `id`.
        pub static TABLE: [Spec; [$( $($id,)* )*].len()] = [
            $( $( Spec {
                id: CommandId::$variant,
                name_len: name_in($usage, $name),
                section: Section::$section,
                grammar: Grammar::$grammar,
                flags: marks!($($flag)*).flags,
                class: marks!($($flag)*).class,
                effect: marks!($($flag)*).effect,
                usage: $usage,
            }, )* )*
        ];

        impl CommandId {
            /// One line saying what the command does.
            pub fn summary(self) -> &'static str {
                match self {
                    $( $( CommandId::$variant => $summary, )* )*
                }
            }

            /// The table row of this command.
            pub fn spec(self) -> &'static Spec {
                // The const check below proves each row sits at `id - 1`,
                // so the fallback is never taken. (An index, not a match:
                // a match compiles to a table of 99 pointers.)
                let [first, ..] = &TABLE;
                TABLE.get(usize::from(self as u8).wrapping_sub(1)).unwrap_or(first)
            }
        }
    };
}

command_table! {
    Authentication {
        1 Login "login" Secret [SESSION] "login <password>" "Log this session in (1025: admin, 0315: log out).";
    }
    State {
        2 State "state" None [READ] "state" "Full FSM state.";
        3 Param "param" None [READ] "param" "All parameters.";
        4 GetParam "get_param" ParamName [READ] "get_param name" "One parameter.";
        5 Ver "ver" None [READ] "ver" "Version information.";
        6 Sysinfo "sysinfo" None [READ] "sysinfo" "Uptime, RAM and loads.";
        7 Diskusage "diskusage" None [READ] "diskusage" "Free disk space.";
        8 Statics "statics" None [READ] "statics" "Communication and recording statistics.";
        9 Machineid "machineid" None [READ] "machineid" "Unique hardware id.";
        10 Hud1 "hud1" None [READ] "hud1" "Keyframes, ENU position and extras.";
        11 Lidarpose "lidarpose" None [READ] "lidarpose" "Lidar pose.";
        12 ApronState "apron_state" None [READ] "apron_state" "Charging pad status.";
        13 MavlinkMsgs "mavlink_msgs" None [READ] "mavlink_msgs" "MAVLink message counts.";
        14 GetSubmapInfo "get_submap_info" None [READ] "get_submap_info" "Map id and keyframe count.";
        15 ShowSp "show_sp" None [READ] "show_sp" "Current setpoint.";
        16 ShowApguid2 "show_apguid2" None [READ] "show_apguid2" "Autopilot guid2.";
        17 Showmsg "showmsg" OptCount [READ] "showmsg [count]" "Recent log messages.";
    }
    Flight {
        18 Takeoff "takeoff" None [NO_ARM MOTION] "takeoff" "Take off.";
        19 Land "land" None [CONSERVATIVE] "land" "Emergency land.";
        20 Rtl "rtl" None [RETURN] "rtl" "Return to launch.";
        21 Mrtl "mrtl" None [RETURN] "mrtl" "Mission return to launch.";
        22 TetherLand "tether_land" None [CONSERVATIVE] "tether_land" "Tethered landing.";
        23 SetSpNed "set_sp_ned" Setpoint [MOTION] "set_sp_ned x:y:z:yaw" "Set the NED setpoint (metres, radians).";
        24 Tunnelfly "tunnelfly" Flag [] "tunnelfly 0|1" "Tunnel fly mode off/on.";
        25 Disarm "disarm" None [CONSERVATIVE] "disarm" "Force disarm.";
        26 Sleep "sleep" None [NO_ARM] "sleep" "Enter sleep mode.";
        27 Wakeup "wakeup" None [] "wakeup" "Wake from sleep.";
        28 AutosleepEnable "autosleep_enable" Flag [NO_ARM NO_LOCK] "autosleep_enable 0|1" "Auto-sleep off/on.";
        29 Zyhk "zyhk" Zyhk [MOTION] "zyhk h1,h2,... [lx,ly,lyaw]" "Hover at several heights, then land.";
        30 RelocatePos "relocate_pos" Pose [NO_ARM] "relocate_pos x,y,z,yaw" "Relocate the position (needs map_locate).";
    }
    Mission {
        31 Mission "mission" Mission [] "mission ext_id:path_or_json" "Submit a mission.";
        32 Plan "plan" Text [] "plan plan_string" "Start a flight plan.";
        33 UnlockPlan "unlock_plan" None [NO_LOCK] "unlock_plan" "Clear the plan execution lock.";
        34 MwList "mw_list" None [READ] "mw_list" "List mission waypoints.";
        35 MwExec "mw_exec" MwExec [MOTION] "mw_exec ext_id:id,id,..." "Execute waypoints by id.";
        36 Ai1Mission "ai1_mission" Ai1Mission [] "ai1_mission task_id:mission_file" "Submit an AI1 mission.";
        37 ObsMission "obs_mission" Flag [] "obs_mission 0|1" "Obstacle mission live mode off/on.";
        38 DumpMissionresult "dump_missionresult" OptCount [READ] "dump_missionresult [ext_id]" "Dump a mission result.";
        39 DumpMissionlist "dump_missionlist" None [READ] "dump_missionlist" "Dump the short mission request list.";
        40 AbortReport "abort_report" OptCount [STOPS_MISSION] "abort_report [abort_id]" "Abort or finish a mission report.";
        41 SetTaskname "set_taskname" TaskName [] "set_taskname name" "Set the current task name.";
    }
    Map {
        42 Savemap "savemap" Name [NO_ARM NO_LOCK] "savemap name" "Save the current map.";
        43 SetMaplocate "set_maplocate" Flag [NO_ARM NO_LOCK] "set_maplocate 0|1" "Map localisation off/on.";
        44 SetMappath "set_mappath" Path [NO_ARM NO_LOCK] "set_mappath path" "Set the localisation map path.";
        45 ListMaps "list_maps" None [READ] "list_maps" "List saved maps.";
        46 RmMap "rm_map" Name [NO_ARM NO_LOCK] "rm_map name" "Remove a saved map.";
    }
    Camera {
        47 Capture "capture" None [] "capture" "Capture an RGB and infrared photo.";
        48 Snapshot "snapshot" None [] "snapshot" "System snapshot.";
        49 Record "record" None [] "record" "Toggle video recording.";
        50 Savebag "savebag" Flag [] "savebag 0|1" "Stop/start bag recording.";
        51 SiyiReboot "siyi_reboot" None [NO_ARM NO_LOCK] "siyi_reboot" "Reboot the SIYI camera/gimbal.";
        52 SiyiFormat "siyi_format" None [NO_ARM NO_LOCK] "siyi_format" "Format the SIYI SD card.";
        53 SiyiCenter "siyi_center" None [] "siyi_center" "Center the SIYI gimbal.";
        54 SiyiInit "siyi_init" None [NO_ARM NO_LOCK] "siyi_init" "Initialise SIYI (close HDMI).";
        55 SiyiDownvideo "siyi_downvideo" OptCount [NO_ARM] "siyi_downvideo [vid]" "Download the latest video.";
        56 SiyiSync "siyi_sync" None [] "siyi_sync" "Trigger SIYI sync.";
    }
    Led {
        57 Ledon "ledon" None [] "ledon" "LED on.";
        58 Ledoff "ledoff" None [] "ledoff" "LED off.";
        59 Ledenable "ledenable" None [] "ledenable" "Enable LED control.";
        60 Leddisable "leddisable" None [] "leddisable" "Disable LED control.";
        61 Ledpwm "ledpwm" Pwm [] "ledpwm pwm" "Set the LED PWM value (0-65535).";
        62 LedBlink "led_blink" None [] "led_blink" "Start LED blinking.";
    }
    Param {
        63 SetParam "set_param" SetParam [NO_ARM NO_LOCK] "set_param name:value" "Set a parameter.";
        64 ResetParam "reset_param" None [NO_ARM NO_LOCK] "reset_param" "Reset all parameters to defaults.";
        65 SaveParam "save_param" Flag [NO_ARM NO_LOCK] "save_param 0|1" "Save parameters persistently.";
        66 Passwd "passwd" NewPassword [NO_LOCK] "passwd new_password" "Change the login password.";
    }
    Apron {
        67 ApronVol "apron_vol" Amount [NO_ARM NO_LOCK] "apron_vol voltage" "Set the charging voltage.";
        68 ApronAmp "apron_amp" Amount [NO_ARM NO_LOCK] "apron_amp amperage" "Set the charging current.";
    }
    System {
        69 RebootNode "reboot_node" None [NO_ARM NO_LOCK] "reboot_node" "Reboot the flight control node.";
        70 RebootAp "reboot_ap" None [NO_ARM NO_LOCK] "reboot_ap" "Reboot the autopilot.";
        71 RebootSystem "reboot_system" None [NO_ARM NO_LOCK] "reboot_system" "Reboot the onboard computer.";
        72 PoweroffSystem "poweroff_system" None [NO_ARM NO_LOCK] "poweroff_system" "Power off the onboard computer.";
        73 PreparePoweroff "prepare_poweroff" None [NO_ARM NO_LOCK] "prepare_poweroff" "Flush logs before power-off.";
        74 RebootDlo "reboot_dlo" None [NO_ARM NO_LOCK] "reboot_dlo" "Reboot DLO.";
        75 RestartDlo "restart_dlo" None [NO_ARM NO_LOCK] "restart_dlo" "Restart the DLO pipeline.";
        76 KillLivox "kill_livox" OptName [NO_ARM NO_LOCK] "kill_livox [script]" "Kill the Livox driver.";
    }
    Lidar {
        77 Lidaronoff "lidaronoff" Flag [NO_ARM NO_LOCK] "lidaronoff 0|1" "Lidar off/on.";
        78 Lidarwarn "lidarwarn" None [READ] "lidarwarn" "Lidar warning zones.";
        79 UtgGet "utg_get" None [] "utg_get" "Trigger a UTG thickness read.";
        80 UtgSet "utg_set" Amount [] "utg_set speed" "Set the UTG sonic speed.";
    }
    Other {
        81 GrabberCtrl "grabber_ctrl" Pwm [] "grabber_ctrl pwm" "Set the grabber PWM value (0-65535).";
        82 Ara8Center "ara8_center" None [] "ara8_center" "ARA8 to center mode.";
        83 Ara8Pitch "ara8_pitch" Angle [] "ara8_pitch angle" "Set the ARA8 pitch (-90..90).";
        84 CvTest "cv_test" None [NO_ARM NO_LOCK] "cv_test" "Trigger a CV server test.";
        85 PreflightCheck "preflight_check" None [NO_ARM] "preflight_check" "Run the preflight checks.";
        86 PreflightEnable "preflight_enable" Flag [NO_ARM NO_LOCK] "preflight_enable 0|1" "Preflight checks before takeoff off/on.";
        87 ClearBags "clear_bags" OptAmount [NO_ARM NO_LOCK] "clear_bags [min_gb]" "Clear old bag files.";
        88 ClearImages "clear_images" OptAmount [NO_ARM NO_LOCK] "clear_images [min_gb]" "Clear old images.";
        89 ListImagedir "list_imagedir" OptCount [READ] "list_imagedir [size]" "List image directories.";
        90 RmImagedir "rm_imagedir" Name [NO_ARM NO_LOCK] "rm_imagedir name" "Remove an image directory.";
        91 TestWp "test_wp" Point [READ] "test_wp x:y:z" "Test waypoint reachability.";
        92 TestListwp "test_listwp" Path [READ] "test_listwp file_path" "Test a waypoint list from a file.";
        93 TestNotif "test_notif" None [] "test_notif" "Test the notification server.";
        94 Savemsg "savemsg" None [] "savemsg" "Save messages to the log.";
        95 BmsSetpower "bms_setpower" Flag [NO_ARM NO_LOCK] "bms_setpower 0|1" "BMS power output off/on.";
        96 BmsSetcharge "bms_setcharge" Flag [NO_ARM NO_LOCK] "bms_setcharge 0|1" "BMS charging off/on.";
        97 Help "help" None [READ] "help" "List the commands.";
        98 AdminLock "admin_lock" None [ADMIN] "admin_lock" "Enable the vehicle-wide lock (admin only).";
        99 AdminUnlock "admin_unlock" None [ADMIN] "admin_unlock" "Disable the vehicle-wide lock (admin only).";
    }
    Control {
        100 Control "control" None [SESSION] "control" "Who is in control of the flight.";
        101 ControlTake "control_take" Override [SESSION] "control_take [failsafe]" "Take control of the flight (failsafe: override a failsafe).";
        102 ControlRelease "control_release" None [SESSION] "control_release" "Release control of the flight.";
    }
}

/// `name`, as the start of `usage` (which begins with the name and a space,
/// or is the name alone): the same text, stored once. A firmware's flash
/// holds every usage line; the names would be about a kilobyte more.
const fn name_in(usage: &'static str, name: &'static str) -> u8 {
    let (head, rest) = match usage.split_at_checked(name.len()) {
        Some(parts) => parts,
        None => ("", ""),
    };
    assert!(
        same(head.as_bytes(), name.as_bytes()) && matches!(rest.as_bytes().first(), None | Some(b' ')),
        "a usage line starts with its command's name"
    );
    assert!(name.len() <= u8::MAX as usize, "a name fits its length byte");
    name.len() as u8
}

// The table is indexed by `id - 1`; a row out of order would break `spec()`.
const _: () = {
    let mut rows: &[Spec] = &TABLE;
    let mut id = 1;
    while let Some((row, rest)) = rows.split_first() {
        assert!(row.id as usize == id, "TABLE rows must be in id order");
        rows = rest;
        id += 1;
    }
};

/// Slots of the name index: a power of two well above the number of
/// commands, so that most lookups look at one slot.
const SLOTS: usize = 256;

/// The name index, built by the compiler: open addressing with linear
/// probing; a slot holds the row + 1 of a command whose name hashes to it
/// (or to a slot before it, taken), 0 when empty.
static BY_NAME: [u8; SLOTS] = name_index();

/// The slot a name hashes to: its length and its first, middle and last
/// bytes mixed by one multiplication. The multiplier was picked for the
/// current names (1.13 probes per name on average, at most 2; an unknown
/// name 1.6); any multiplier is correct, a worse one only probes more.
const fn slot_of(name: &[u8]) -> usize {
    let (first, last, middle) = match (name.first(), name.last(), name.split_at_checked(name.len() / 2)) {
        (Some(&first), Some(&last), Some((_, [middle, ..]))) => (first, last, *middle),
        _ => (0, 0, 0),
    };
    let x = name.len() as u32 | (first as u32) << 8 | (last as u32) << 16 | (middle as u32) << 24;
    (x.wrapping_mul(51_351) >> 24) as usize % SLOTS
}

/// Byte equality, for compile time.
const fn same(a: &[u8], b: &[u8]) -> bool {
    if a.len() != b.len() {
        return false;
    }
    let (mut a, mut b) = (a, b);
    while let (Some((x, a_rest)), Some((y, b_rest))) = (a.split_first(), b.split_first()) {
        if *x != *y {
            return false;
        }
        a = a_rest;
        b = b_rest;
    }
    true
}

/// `index[i]`, for compile time (0 past the end).
const fn at(index: &[u8], i: usize) -> u8 {
    match index.split_at_checked(i) {
        Some((_, [v, ..])) => *v,
        _ => 0,
    }
}

/// The name of the command in slot value `v` (row + 1), for compile time.
const fn name_of(v: u8) -> &'static [u8] {
    match TABLE.split_at_checked((v as usize).wrapping_sub(1)) {
        Some((_, [spec, ..])) => spec.name().as_bytes(),
        _ => b"",
    }
}

const fn name_index() -> [u8; SLOTS] {
    let mut index = [0u8; SLOTS];
    let mut rows: &[Spec] = &TABLE;
    let mut row = 0;
    while let Some((spec, rest)) = rows.split_first() {
        let name = spec.name().as_bytes();
        let mut slot = slot_of(name);
        while at(&index, slot) != 0 {
            // Duplicate names would make lookup ambiguous.
            assert!(
                !same(name_of(at(&index, slot)), name),
                "command names must be unique"
            );
            slot = (slot + 1) % SLOTS;
        }
        if let Some((_, [free, ..])) = index.split_at_mut_checked(slot) {
            *free = row + 1;
        }
        rows = rest;
        row += 1;
    }
    index
}

/// Finds a command by its wire name (exact, case-sensitive).
pub fn lookup(name: &str) -> Option<&'static Spec> {
    let mut slot = slot_of(name.as_bytes());
    // The index is never full, so an empty slot ends every search; the
    // bound is for the compiler.
    for _ in 0..SLOTS {
        let row = usize::from(*BY_NAME.get(slot)?).checked_sub(1)?;
        let spec = TABLE.get(row)?;
        if spec.is_named(name) {
            return Some(spec);
        }
        slot = (slot + 1) % SLOTS;
    }
    None
}

impl CommandId {
    /// The command with this id, if any (0 and ids past the table are none).
    pub fn from_u8(id: u8) -> Option<CommandId> {
        TABLE.get(usize::from(id).checked_sub(1)?).map(|s| s.id)
    }

    /// The wire name.
    pub fn name(self) -> &'static str {
        self.spec().name()
    }

    /// Where the specification lists it.
    pub fn section(self) -> Section {
        self.spec().section
    }

    /// Finds a command by its wire name.
    pub fn from_name(name: &str) -> Option<CommandId> {
        lookup(name).map(|s| s.id)
    }
}

impl From<CommandId> for u8 {
    fn from(id: CommandId) -> u8 {
        id as u8
    }
}
