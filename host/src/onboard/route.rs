//! Which side of [`super::Onboard`] owns each command.

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

/// The owner of `id`: by the command table's section, with the
/// exceptions the module doc of [`super`] lists.
pub fn owner(id: C) -> Owner {
    match id {
        C::State | C::Statics | C::Hud1 => Owner::Both,
        C::SetMaplocate | C::RebootAp | C::KillLivox => Owner::Vehicle,
        C::Ver | C::Sysinfo | C::Diskusage | C::Machineid | C::GetSubmapInfo | C::Showmsg => Owner::Companion,
        C::Savebag | C::ClearBags | C::ClearImages | C::ListImagedir | C::RmImagedir => Owner::Companion,
        C::TestNotif | C::CvTest | C::Savemsg | C::Passwd => Owner::Companion,
        _ => match id.spec().section {
            Section::Map | Section::System => Owner::Companion,
            _ => Owner::Vehicle,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lluav_core::TABLE;

    #[test]
    fn the_companion_owns_the_machine_and_the_vehicle_owns_flight() {
        let companion: Vec<_> = TABLE
            .iter()
            .filter(|s| owner(s.id) == Owner::Companion)
            .map(|s| s.name)
            .collect();
        assert_eq!(
            companion,
            [
                "ver",
                "sysinfo",
                "diskusage",
                "machineid",
                "get_submap_info",
                "showmsg",
                "savemap",
                "set_mappath",
                "list_maps",
                "rm_map",
                "savebag",
                "passwd",
                "reboot_node",
                "reboot_system",
                "poweroff_system",
                "prepare_poweroff",
                "reboot_dlo",
                "restart_dlo",
                "cv_test",
                "clear_bags",
                "clear_images",
                "list_imagedir",
                "rm_imagedir",
                "test_notif",
                "savemsg",
            ]
        );
        for spec in TABLE.iter().filter(|s| {
            matches!(
                s.section,
                Section::Flight | Section::Mission | Section::Led | Section::Apron | Section::Lidar
            )
        }) {
            assert_eq!(owner(spec.id), Owner::Vehicle, "{}", spec.name);
        }
    }
}
