//! Simulated peripherals: LED, SIYI camera and gimbal, apron (charging pad),
//! BMS, lidar, UTG thickness gauge, grabber, ARA8 arm, and the computers
//! that the reboot commands would restart. Each keeps the state its
//! commands set and reports it under one response field.

use lluav_core::Fields;

use super::error::{SimError, SimResult};

/// Largest apron charging voltage, V.
pub const APRON_MAX_V: f32 = 60.0;
/// Largest apron charging current, A.
pub const APRON_MAX_A: f32 = 30.0;
/// Largest UTG sonic speed, m/s (faster than any common material).
pub const UTG_MAX_SPEED: f32 = 20_000.0;
/// Grabber PWM above which it counts as open, µs.
pub const GRABBER_OPEN_PWM: u16 = 1500;
/// Simulated UTG echo round trip, µs.
const UTG_ECHO_US: f64 = 3.4;

/// The LED.
#[derive(Clone, Copy, Debug)]
pub struct Led {
    /// Whether LED control is enabled.
    pub enabled: bool,
    /// Whether it is lit.
    pub on: bool,
    /// Whether it blinks.
    pub blink: bool,
    /// PWM value.
    pub pwm: u16,
}

impl Led {
    /// Fails unless LED control is enabled.
    pub fn require_enabled(&self) -> SimResult {
        if self.enabled {
            Ok(())
        } else {
            Err(SimError::Refused(
                "LED control is disabled: ledenable first".into(),
            ))
        }
    }

    /// Writes `led`.
    pub fn write(&self, out: &mut Fields<'_>) {
        out.object("led", |o| {
            o.bool("enabled", self.enabled)
                .bool("on", self.on)
                .bool("blink", self.blink)
                .u64("pwm", self.pwm.into());
        });
    }
}

/// The SIYI camera and gimbal.
#[derive(Clone, Debug, Default)]
pub struct Siyi {
    /// Whether it records video.
    pub recording: bool,
    /// Ids of the videos on its SD card, oldest first.
    pub videos: Vec<u32>,
    /// The next video id.
    pub next_vid: u32,
    /// Whether the gimbal is centred.
    pub centered: bool,
    /// Whether HDMI output is on (`siyi_init` closes it).
    pub hdmi: bool,
    /// Reboots so far.
    pub reboots: u32,
    /// Syncs so far.
    pub syncs: u32,
}

impl Siyi {
    /// Toggles recording; stopping stores a new video on the SD card and
    /// returns its id.
    pub fn toggle_record(&mut self) -> Option<u32> {
        self.recording = !self.recording;
        if self.recording {
            return None;
        }
        self.next_vid += 1;
        self.videos.push(self.next_vid);
        Some(self.next_vid)
    }

    /// Writes `siyi`.
    pub fn write(&self, out: &mut Fields<'_>) {
        out.object("siyi", |o| {
            o.bool("recording", self.recording)
                .array("videos", |a| {
                    self.videos.iter().for_each(|&v| {
                        a.u64(v.into());
                    })
                })
                .bool("centered", self.centered)
                .bool("hdmi", self.hdmi)
                .u64("reboots", self.reboots.into())
                .u64("syncs", self.syncs.into());
        });
    }
}

/// The charging pad.
#[derive(Clone, Copy, Debug)]
pub struct Apron {
    /// Charging voltage, V.
    pub voltage: f32,
    /// Charging current, A.
    pub current: f32,
}

impl Apron {
    /// Sets the voltage (0..=[`APRON_MAX_V`]).
    pub fn set_voltage(&mut self, v: f32) -> SimResult {
        self.voltage = checked("voltage", v, APRON_MAX_V)?;
        Ok(())
    }

    /// Sets the current (0..=[`APRON_MAX_A`]).
    pub fn set_current(&mut self, a: f32) -> SimResult {
        self.current = checked("amperage", a, APRON_MAX_A)?;
        Ok(())
    }

    /// Writes `apron_status`.
    pub fn write(&self, out: &mut Fields<'_>, charging: bool) {
        out.object("apron_status", |o| {
            o.f32("voltage", self.voltage)
                .f32("current", self.current)
                .bool("charging", charging);
        });
    }
}

fn checked(what: &str, v: f32, max: f32) -> SimResult<f32> {
    if v > max {
        return Err(SimError::Refused(format!("{what} {v} above {max}")));
    }
    Ok(v)
}

/// The battery management system.
#[derive(Clone, Copy, Debug)]
pub struct Bms {
    /// Power output on.
    pub power: bool,
    /// Charging on.
    pub charging: bool,
}

impl Bms {
    /// Writes `bms`.
    pub fn write(&self, out: &mut Fields<'_>, battery: f64) {
        out.object("bms", |o| {
            o.bool("power", self.power)
                .bool("charging", self.charging)
                .f64("battery", round1(battery));
        });
    }
}

/// The Livox lidar and its driver.
#[derive(Clone, Debug)]
pub struct Lidar {
    /// Powered.
    pub on: bool,
    /// Driver running.
    pub driver: bool,
    /// The script the last `kill_livox` named.
    pub last_kill_script: Option<String>,
}

impl Lidar {
    /// Writes `lidar`.
    pub fn write(&self, out: &mut Fields<'_>) {
        out.object("lidar", |o| {
            o.bool("on", self.on).bool("driver", self.driver);
            match &self.last_kill_script {
                Some(s) => o.str("kill_script", s),
                None => o.null("kill_script"),
            };
        });
    }

    /// Writes `warn_zones`: the simulated world is an empty field, so the
    /// only obstacle is the ground below; it warns under 1 m and alarms
    /// under 0.3 m while the lidar runs.
    pub fn write_warnings(&self, out: &mut Fields<'_>, altitude: f64, airborne: bool) {
        out.bool("lidar_on", self.on && self.driver);
        out.array("warn_zones", |a| {
            if !(self.on && self.driver && airborne) {
                return;
            }
            let level = if altitude < 0.3 {
                "alarm"
            } else if altitude < 1.0 {
                "warn"
            } else {
                return;
            };
            a.object(|o| {
                o.str("sector", "down")
                    .f64("distance_m", round1(altitude))
                    .str("level", level);
            });
        });
    }
}

/// The ultrasonic thickness gauge.
#[derive(Clone, Copy, Debug)]
pub struct Utg {
    /// Sonic speed of the material, m/s.
    pub speed: f32,
    /// Reads so far.
    pub reads: u32,
}

impl Utg {
    /// Sets the sonic speed (up to [`UTG_MAX_SPEED`]; 0 is refused).
    pub fn set_speed(&mut self, v: f32) -> SimResult {
        if v <= 0.0 {
            return Err(SimError::Refused("UTG sonic speed must be above 0".into()));
        }
        self.speed = checked("UTG sonic speed", v, UTG_MAX_SPEED)?;
        Ok(())
    }

    /// Writes `utg`: the thickness is half the echo's round trip at the
    /// material's sonic speed.
    pub fn write(&self, out: &mut Fields<'_>) {
        let thickness_mm = f64::from(self.speed) * UTG_ECHO_US * 1e-6 / 2.0 * 1000.0;
        out.object("utg", |o| {
            o.f32("speed", self.speed)
                .f64("thickness_mm", (thickness_mm * 1000.0).round() / 1000.0)
                .u64("reads", self.reads.into());
        });
    }
}

/// The ARA8 arm.
#[derive(Clone, Copy, Debug)]
pub struct Ara8 {
    /// Centred (after `ara8_center`) or pitched.
    pub centered: bool,
    /// Pitch, degrees.
    pub pitch: f32,
}

impl Ara8 {
    /// Writes `ara8`.
    pub fn write(&self, out: &mut Fields<'_>) {
        out.object("ara8", |o| {
            o.str("mode", if self.centered { "center" } else { "pitch" })
                .f32("pitch", self.pitch);
        });
    }
}

/// A simulated computer or process the reboot commands restart.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    /// The flight control node.
    Node,
    /// The autopilot.
    Autopilot,
    /// The onboard computer.
    System,
    /// DLO (reboot).
    Dlo,
    /// The DLO pipeline (restart).
    DloPipeline,
}

impl Target {
    /// Its name in `reboot.target`.
    pub fn name(self) -> &'static str {
        match self {
            Target::Node => "node",
            Target::Autopilot => "autopilot",
            Target::System => "system",
            Target::Dlo => "dlo",
            Target::DloPipeline => "dlo_pipeline",
        }
    }
}

/// Every simulated device.
#[derive(Clone, Debug)]
pub struct Devices {
    /// LED.
    pub led: Led,
    /// SIYI camera.
    pub siyi: Siyi,
    /// Charging pad.
    pub apron: Apron,
    /// BMS.
    pub bms: Bms,
    /// Lidar.
    pub lidar: Lidar,
    /// UTG gauge.
    pub utg: Utg,
    /// Grabber PWM.
    pub grabber_pwm: u16,
    /// ARA8 arm.
    pub ara8: Ara8,
    /// Tunnel fly mode.
    pub tunnelfly: bool,
    /// Auto-sleep enabled.
    pub autosleep: bool,
    /// Preflight checks required before takeoff.
    pub preflight: bool,
    /// Map localisation enabled.
    pub map_locate: bool,
    /// Simulated restarts, per target, in [`Target`] order.
    pub restarts: [u32; 5],
    /// A simulated power-off was requested (the real machine is untouched).
    pub poweroff_requested: bool,
    /// Notifications sent by `test_notif`.
    pub notifications: u32,
    /// CV server tests run.
    pub cv_tests: u32,
}

impl Default for Devices {
    fn default() -> Self {
        Devices {
            led: Led {
                enabled: true,
                on: false,
                blink: false,
                pwm: 0,
            },
            siyi: Siyi {
                hdmi: true,
                ..Siyi::default()
            },
            apron: Apron {
                voltage: 25.2,
                current: 5.0,
            },
            bms: Bms {
                power: true,
                charging: false,
            },
            lidar: Lidar {
                on: true,
                driver: true,
                last_kill_script: None,
            },
            utg: Utg {
                speed: 5920.0,
                reads: 0,
            },
            grabber_pwm: 1000,
            ara8: Ara8 {
                centered: true,
                pitch: 0.0,
            },
            tunnelfly: false,
            autosleep: false,
            preflight: false,
            map_locate: false,
            restarts: [0; 5],
            poweroff_requested: false,
            notifications: 0,
            cv_tests: 0,
        }
    }
}

impl Devices {
    /// Records a simulated restart of `target` and writes `reboot`.
    pub fn restart(&mut self, target: Target, out: &mut Fields<'_>) {
        let slot = &mut self.restarts[target as usize];
        *slot += 1;
        let count = *slot;
        tracing::warn!(
            target = target.name(),
            "simulated restart (the real machine is untouched)"
        );
        out.object("reboot", |o| {
            o.str("target", target.name())
                .bool("simulated", true)
                .u64("count", count.into());
        });
    }

    /// Writes `grabber`.
    pub fn write_grabber(&self, out: &mut Fields<'_>) {
        out.object("grabber", |o| {
            o.u64("pwm", self.grabber_pwm.into())
                .bool("open", self.grabber_pwm > GRABBER_OPEN_PWM);
        });
    }
}

/// `v` rounded to one decimal, for human-facing percentages.
pub fn round1(v: f64) -> f64 {
    (v * 10.0).round() / 10.0
}
