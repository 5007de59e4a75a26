//! Which side of [`super::Onboard`] owns each command: the command
//! table's section decides ([`Section::Map`] and [`Section::System`] are
//! the companion computer's, every other section the vehicle's), except
//! for the commands in [`EXCEPTIONS`], written once below.

use lluav_core::{CommandId as C, Section};

/// Who answers a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Owner {
    /// The vehicle backend.
    Vehicle,
    /// The companion computer.
    Companion,
    /// The vehicle writes its fields, then the companion adds its own.
    Both,
}

/// Declares [`EXCEPTIONS`] and writes its list into its documentation,
/// so the list a reader sees is the one the daemon routes by.
macro_rules! exceptions {
    ($($owner:ident: [$($cmd:ident),* $(,)?];)*) => {
        /// The commands whose owner is not their section's:
        $(
            #[doc = concat!("- ", stringify!($owner), ":", $(" [`", stringify!($cmd), "`](C::", stringify!($cmd), ")"),*)]
        )*
        pub const EXCEPTIONS: &[(C, Owner)] = &[$($((C::$cmd, Owner::$owner),)*)*];
    };
}

exceptions! {
    // One `state` object (and `statics`, `hud1`) that both fill.
    Both: [State, Statics, Hud1];
    // The autopilot's and the lidar's, though listed with the machine.
    Vehicle: [SetMaplocate, RebootAp, KillLivox];
    // The machine's, though listed with telemetry, missions and devices.
    Companion: [
        Ver, Sysinfo, Diskusage, Machineid, GetSubmapInfo, Showmsg, Savebag, ClearBags, ClearImages,
        ListImagedir, RmImagedir, TestNotif, CvTest, Savemsg, Passwd,
    ];
}

/// The owner of a section's commands.
fn by_section(section: Section) -> Owner {
    match section {
        Section::Map | Section::System => Owner::Companion,
        _ => Owner::Vehicle,
    }
}

/// The owner of `id`.
pub fn owner(id: C) -> Owner {
    EXCEPTIONS
        .iter()
        .find(|(c, _)| *c == id)
        .map_or_else(|| by_section(id.spec().section), |&(_, owner)| owner)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_exception_differs_from_its_section_and_is_listed_once() {
        for (i, &(id, owner)) in EXCEPTIONS.iter().enumerate() {
            assert_ne!(
                by_section(id.spec().section),
                owner,
                "{} needs no exception",
                id.name()
            );
            assert!(
                EXCEPTIONS[..i].iter().all(|(c, _)| *c != id),
                "{} listed twice",
                id.name()
            );
        }
    }
}
