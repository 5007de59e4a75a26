//! The companion computer: the Linux machine on board that lluavd runs on.
//!
//! Whatever vehicle backend flies (the simulator, an autopilot over
//! MAVLink), the commands about this machine are answered here, the same
//! way: maps, images, bags, videos and logs as real files under the data
//! directory ([`crate::files`]); `sysinfo`, `diskusage` and `machineid` from the
//! real machine; `showmsg`/`savemsg` from the daemon's recent log; the
//! reboots of the machine and of its nodes (simulated and logged: nothing
//! here ever reboots or powers off the real machine); and the password file
//! `passwd` writes. [`crate::onboard`] lists which commands come here.
//!
//! Time never comes from a clock here: a request's time is
//! [`lluav_core::Context::now_ms`], and [`Companion::tick`] moves the
//! nodes' uptime.

mod bags;
mod error;
mod fit;
mod images;
mod logs;
mod maps;
mod nodes;
mod password;
mod system;

use std::io;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use lluav_core::{Command, CommandId, Context, Fields, Section};

use crate::files::{Files, Saved};
use crate::recent_log::RecentLog;
use crate::vehicle::Snapshot;
use bags::Bags;
pub use error::Error;
use error::Result;
use logs::Logs;
use nodes::Nodes;
pub use nodes::machine_id;
use password::Password;

/// How to start the [`Companion`].
#[derive(Clone, Debug)]
pub struct CompanionConfig {
    /// Where maps, images, bags, logs, saved parameters and the password
    /// live.
    pub data_dir: PathBuf,
    /// The daemon's recent log lines, for `showmsg`/`savemsg`.
    pub log: RecentLog,
    /// Whether the daemon's configuration (`--password`, `LLUAV_PASSWORD`,
    /// the config file) sets the password, so that `passwd` must refuse.
    pub password_pinned: bool,
    /// Where `state.uplink` comes from; `None`: `off`.
    pub uplink: Option<UplinkReport>,
}

/// The state of this machine's link to an MQTT broker, for `state.uplink`
/// (`up`, `down`): read when `state` is answered.
#[derive(Clone)]
pub struct UplinkReport(Arc<dyn Fn() -> &'static str + Send + Sync>);

impl UplinkReport {
    /// A report that asks `read` each time.
    pub fn new(read: impl Fn() -> &'static str + Send + Sync + 'static) -> Self {
        UplinkReport(Arc::new(read))
    }
}

impl std::fmt::Debug for UplinkReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "UplinkReport({})", (self.0)())
    }
}

/// File in the data directory holding what [`Kept`] keeps.
const STATE_FILE: &str = "state.json";

/// What the companion keeps across a restart, besides the password.
#[derive(Clone, Debug, Default, serde::Deserialize, serde::Serialize)]
#[serde(default)]
pub(crate) struct Kept {
    /// Lock mode (`admin_lock`): a daemon that restarts while an admin
    /// holds the lock comes back locked.
    pub(crate) lock_mode: bool,
    /// The map in use (`set_mappath`), relative to the map directory.
    pub(crate) map_path: Option<String>,
}

/// The companion computer's state.
#[derive(Debug)]
pub struct Companion {
    files: Files,
    logs: Logs,
    password: Password,
    kept: Saved<Kept>,
    bags: Bags,
    nodes: Nodes,
    uplink: Option<UplinkReport>,
}

impl Companion {
    /// Creates the data directory and its subdirectories and reads the
    /// saved password.
    pub fn open(cfg: CompanionConfig) -> io::Result<Companion> {
        let files = Files::open(&cfg.data_dir)?;
        let password = Password::load(files.root(), cfg.password_pinned)?;
        let kept = Saved::load(files.root().join(STATE_FILE))?;
        Ok(Companion {
            files,
            logs: Logs::new(cfg.log),
            password,
            kept,
            bags: Bags::default(),
            nodes: Nodes::default(),
            uplink: cfg.uplink,
        })
    }

    /// The data directory, for a vehicle backend's files.
    pub fn files(&self) -> &Files {
        &self.files
    }

    /// Carries out a command this machine owns; `vehicle` is what the
    /// vehicle backend reports of itself right now.
    pub fn execute(
        &mut self,
        cmd: &Command<'_>,
        ctx: &Context,
        vehicle: &Snapshot,
        out: &mut Fields<'_>,
    ) -> Result {
        let (files, now_ms) = (&self.files, ctx.now_ms);
        match cmd.id() {
            CommandId::Showmsg | CommandId::Savemsg => self.logs.run(cmd, files, now_ms, out),
            CommandId::Savebag | CommandId::ClearBags => self.bags.run(cmd, files, now_ms, out),
            CommandId::ClearImages | CommandId::ListImagedir | CommandId::RmImagedir => {
                images::run(cmd, files, now_ms, out)
            }
            CommandId::Hud1 | CommandId::GetSubmapInfo => {
                maps::write_kfs(self.kept.get(), vehicle, out);
                Ok(())
            }
            CommandId::TestNotif | CommandId::CvTest => {
                self.nodes.serve(cmd.id(), out);
                Ok(())
            }
            id => match id.spec().section {
                Section::State => self.report(id, vehicle, out),
                Section::Map => maps::run(cmd, files, now_ms, vehicle, &mut self.kept, out),
                Section::System => self.system(id, now_ms, out),
                _ => Err(Error::NotOwned(id.name())),
            },
        }
    }

    fn report(&self, id: CommandId, vehicle: &Snapshot, out: &mut Fields<'_>) -> Result {
        match id {
            CommandId::Ver => nodes::write_version(vehicle, out),
            CommandId::Sysinfo => nodes::write_sysinfo(out)?,
            CommandId::Machineid => nodes::write_machine_id(out)?,
            CommandId::Statics => {
                self.bags.write_statics(out);
                self.nodes.write_statics(out);
            }
            CommandId::Diskusage => {
                out.u64("available_MB", self.files.free_bytes()? >> 20);
            }
            id => return Err(Error::NotOwned(id.name())),
        }
        Ok(())
    }

    /// Reboots and power-off: what is pending is flushed first, as a real
    /// machine's shutdown would.
    fn system(&mut self, id: CommandId, now_ms: i64, out: &mut Fields<'_>) -> Result {
        if matches!(
            id,
            CommandId::RebootSystem | CommandId::PoweroffSystem | CommandId::PreparePoweroff
        ) {
            self.bags
                .flush()
                .map_err(|e| Error::io("flush before power-off", e))?;
        }
        if id == CommandId::PreparePoweroff {
            out.bool("prepared", true);
            return self.logs.save(&self.files, now_ms, out);
        }
        self.nodes.restart(id, out);
        Ok(())
    }

    /// Writes this machine's members of `state`.
    pub fn write_state(&self, state: &mut Fields<'_>) {
        state.bool("recording_bag", self.bags.recording());
        state.str("uplink", self.uplink.as_ref().map_or("off", |read| (read.0)()));
    }

    /// Moves time on by `dt` of wall time: the nodes' uptime grows and a
    /// recording bag samples the vehicle's pose.
    pub fn tick(&mut self, dt: Duration, vehicle: &Snapshot) {
        self.nodes.tick(dt);
        self.bags.sample(vehicle);
    }

    /// Whether a bag is recording (it samples the vehicle every tick).
    pub fn recording(&self) -> bool {
        self.bags.recording()
    }

    /// Persists what is pending: a recording bag's buffered samples.
    pub fn flush(&mut self) -> io::Result<()> {
        self.bags.flush()
    }

    /// The password an earlier `passwd` saved, if any.
    pub fn stored_password(&self) -> Option<String> {
        self.password.stored()
    }

    /// Saves a new password for good, unless the configuration pins it.
    pub fn set_password(&mut self, new: &str) -> Result {
        self.password.set(new)
    }

    /// Lock mode as last saved.
    pub fn stored_lock_mode(&self) -> bool {
        self.kept.get().lock_mode
    }

    /// Saves lock mode for good, before it takes effect.
    pub fn set_lock_mode(&mut self, on: bool) -> Result {
        self.kept
            .update(|k| k.lock_mode = on)
            .map_err(|e| Error::io("save lock mode", e))?;
        tracing::info!(lock_mode = on, "lock mode saved");
        Ok(())
    }
}
