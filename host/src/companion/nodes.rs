//! The machine and its processes: version, `sysinfo`, `machineid`, the
//! simulated reboots of the machine and its nodes (logged; the real machine
//! is never touched), and the notification and CV servers' self-tests.

use std::path::Path;
use std::time::Duration;

use lluav_core::{CommandId, Fields, TABLE};

use super::error::{Error, Result};
use super::system;
use crate::vehicle::Snapshot;

/// Where the machine id is read from.
const MACHINE_ID_FILE: &str = "/etc/machine-id";

/// What the reboot commands restart.
const TARGETS: [(CommandId, &str); 5] = [
    (CommandId::RebootNode, "node"),
    (CommandId::RebootSystem, "system"),
    (CommandId::PoweroffSystem, "poweroff"),
    (CommandId::RebootDlo, "dlo"),
    (CommandId::RestartDlo, "dlo_pipeline"),
];

/// The processes of the companion computer, simulated.
#[derive(Debug, Default)]
pub(super) struct Nodes {
    /// Wall time since the flight control node (re)started.
    node_up: Duration,
    /// Simulated restarts, per target, in [`TARGETS`] order.
    restarts: [u32; TARGETS.len()],
    notifications: u32,
    cv_tests: u32,
}

impl Nodes {
    pub(super) fn tick(&mut self, dt: Duration) {
        self.node_up += dt;
    }

    /// Records a simulated restart and writes `reboot` (or `poweroff`).
    pub(super) fn restart(&mut self, id: CommandId, out: &mut Fields<'_>) {
        let Some(i) = TARGETS.iter().position(|(t, _)| *t == id) else {
            return;
        };
        let (slot, target) = (&mut self.restarts[i], TARGETS[i].1);
        *slot += 1;
        let count = *slot;
        if matches!(id, CommandId::RebootNode | CommandId::RebootSystem) {
            self.node_up = Duration::ZERO;
        }
        tracing::warn!(
            target,
            "simulated {target} restart (the real machine is untouched)"
        );
        let key = if id == CommandId::PoweroffSystem {
            "poweroff"
        } else {
            "reboot"
        };
        out.object(key, |o| {
            o.str("target", target)
                .bool("simulated", true)
                .u64("count", count.into());
        });
    }

    /// `test_notif` and `cv_test`: the servers answer their self-test.
    pub(super) fn serve(&mut self, id: CommandId, out: &mut Fields<'_>) {
        if id == CommandId::TestNotif {
            self.notifications += 1;
            tracing::info!(seq = self.notifications, "test notification");
            out.object("notif", |o| {
                o.bool("sent", true).u64("seq", self.notifications.into());
            });
        } else {
            self.cv_tests += 1;
            out.object("cv_test", |o| {
                o.bool("ok", true).u64("run", self.cv_tests.into());
            });
        }
    }

    /// Writes `node_boot_sec`.
    pub(super) fn write_statics(&self, out: &mut Fields<'_>) {
        out.u64("node_boot_sec", self.node_up.as_secs());
    }
}

/// Writes `version`: this program, the vehicle backend and the machine.
pub(super) fn write_version(vehicle: &Snapshot, out: &mut Fields<'_>) {
    out.object("version", |o| {
        o.str("lluav", env!("CARGO_PKG_VERSION"))
            .str("backend", vehicle.backend)
            .u64("commands", TABLE.len() as u64)
            .str("os", std::env::consts::OS)
            .str("arch", std::env::consts::ARCH);
    });
}

/// Writes `sysinfo` from `sysinfo(2)`.
pub(super) fn write_sysinfo(out: &mut Fields<'_>) -> Result {
    let info = system::sysinfo().map_err(|e| Error::io("sysinfo()", e))?;
    out.object("sysinfo", |o| {
        o.u64("uptime", info.uptime_s)
            .u64("ram_total_MB", info.ram_total_mb)
            .u64("ram_free_MB", info.ram_free_mb)
            .array("loads", |a| {
                info.loads.iter().for_each(|&l| {
                    a.f64((l * 100.0).round() / 100.0);
                })
            })
            .u64("procs", info.procs.into());
    });
    Ok(())
}

/// The real machine's id (`/etc/machine-id`).
pub fn machine_id() -> std::io::Result<String> {
    system::machine_id(Path::new(MACHINE_ID_FILE))
}

/// Writes `did`, the machine id.
pub(super) fn write_machine_id(out: &mut Fields<'_>) -> Result {
    let did = machine_id().map_err(|e| Error::io(format!("read {MACHINE_ID_FILE}"), e))?;
    out.str("did", &did);
    Ok(())
}
