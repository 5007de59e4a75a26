//! Simulated peripherals on the airframe: LED, apron (charging pad), BMS,
//! lidar and its Livox driver, UTG thickness gauge, grabber, ARA8 arm. Each
//! keeps the state its commands set and reports it under one response
//! field; [`Devices::run`] hands each command to its device.

use lluav_core::{Args, Command, CommandId as C, Fields, Number};

use super::error::{SimError, SimResult};

/// Largest apron charging voltage, V.
const APRON_MAX_V: f32 = 60.0;
/// Largest apron charging current, A.
const APRON_MAX_A: f32 = 30.0;
/// Largest UTG sonic speed, m/s (faster than any common material).
const UTG_MAX_SPEED: f32 = 20_000.0;
/// Grabber PWM above which it counts as open, µs.
const GRABBER_OPEN_PWM: u16 = 1500;
/// Simulated UTG echo round trip, µs.
const UTG_ECHO_US: f64 = 3.4;

/// What the devices need to know of the flight.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Airframe {
    /// Height above ground, m.
    pub(crate) altitude: f64,
    /// Off the ground.
    pub(crate) airborne: bool,
    /// Motors armed.
    pub(crate) armed: bool,
    /// Battery, percent.
    pub(crate) battery: f64,
}

/// Every simulated device.
#[derive(Clone, Debug)]
pub(crate) struct Devices {
    led: Led,
    apron: Apron,
    bms: Bms,
    lidar: Lidar,
    utg: Utg,
    grabber_pwm: u16,
    ara8: Ara8,
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
        }
    }
}

impl Devices {
    /// The device commands: LED, apron, BMS, lidar, UTG, grabber, ARA8,
    /// `kill_livox` and `apron_state`.
    pub(crate) fn run(&mut self, cmd: &Command<'_>, air: Airframe, out: &mut Fields<'_>) -> SimResult {
        match (cmd.id(), cmd.args()) {
            (C::Ledon | C::Ledoff | C::Ledenable | C::Leddisable | C::Ledpwm | C::LedBlink, args) => {
                self.led.run(cmd.id(), args, out)?
            }
            (C::ApronVol, &Args::Amount(v)) => self.set_apron(v, APRON_MAX_V, "voltage", out)?,
            (C::ApronAmp, &Args::Amount(a)) => self.set_apron(a, APRON_MAX_A, "amperage", out)?,
            (C::ApronState, _) => {
                self.apron.write(out, self.bms.charging && !air.armed);
                out.bool("apron_comm", true);
            }
            (C::BmsSetpower, &Args::Flag(on)) => self.bms.power = on,
            (C::BmsSetcharge, &Args::Flag(on)) => self.bms.charging = on,
            (C::Lidaronoff | C::KillLivox | C::Lidarwarn, args) => self.lidar.run(args, air, out),
            (C::UtgGet, _) => self.utg.reads += 1,
            (C::UtgSet, &Args::Amount(speed)) => self.utg.set_speed(speed)?,
            (C::GrabberCtrl, &Args::Pwm(pwm)) => self.grabber(pwm, out),
            (C::Ara8Center | C::Ara8Pitch, args) => self.ara8.run(args, out),
            (id, _) => return Err(SimError::NotOwned(id.name())),
        }
        match cmd.id() {
            C::BmsSetpower | C::BmsSetcharge => self.bms.write(out, air.battery),
            C::UtgGet | C::UtgSet => self.utg.write(out),
            _ => {}
        }
        Ok(())
    }

    fn set_apron(&mut self, v: Number<'_>, max: f32, what: &str, out: &mut Fields<'_>) -> SimResult {
        let v = checked(what, v, max)?;
        if what == "voltage" {
            self.apron.voltage = v;
        } else {
            self.apron.current = v;
        }
        self.apron.write(out, self.bms.charging);
        Ok(())
    }

    fn grabber(&mut self, pwm: u16, out: &mut Fields<'_>) {
        self.grabber_pwm = pwm;
        out.object("grabber", |o| {
            o.u64("pwm", pwm.into()).bool("open", pwm > GRABBER_OPEN_PWM);
        });
    }

    /// Whether the battery powers the vehicle (`bms_setpower`).
    pub(crate) fn powered(&self) -> bool {
        self.bms.power
    }

    /// Whether the pad charges the battery.
    pub(crate) fn charging(&self) -> bool {
        self.bms.charging
    }

    /// Whether the lidar and its driver run (a preflight check).
    pub(crate) fn lidar_running(&self) -> bool {
        self.lidar.on && self.lidar.driver
    }
}

/// The LED.
#[derive(Clone, Copy, Debug)]
struct Led {
    enabled: bool,
    on: bool,
    blink: bool,
    pwm: u16,
}

impl Led {
    fn run(&mut self, id: C, args: &Args<'_>, out: &mut Fields<'_>) -> SimResult {
        let enabling = matches!(id, C::Ledenable | C::Leddisable);
        if !self.enabled && !enabling {
            return Err(SimError::LedDisabled);
        }
        match (id, args) {
            (C::Ledon, _) => (self.on, self.blink) = (true, false),
            (C::Ledoff, _) => (self.on, self.blink) = (false, false),
            (C::LedBlink, _) => (self.on, self.blink) = (true, true),
            (C::Ledpwm, &Args::Pwm(pwm)) => (self.pwm, self.on) = (pwm, pwm > 0),
            (C::Ledenable, _) => self.enabled = true,
            _ => (self.enabled, self.on, self.blink) = (false, false, false),
        }
        out.object("led", |o| {
            o.bool("enabled", self.enabled)
                .bool("on", self.on)
                .bool("blink", self.blink)
                .u64("pwm", self.pwm.into());
        });
        Ok(())
    }
}

/// The charging pad.
#[derive(Clone, Copy, Debug)]
struct Apron {
    voltage: f32,
    current: f32,
}

impl Apron {
    fn write(&self, out: &mut Fields<'_>, charging: bool) {
        out.object("apron_status", |o| {
            o.f32("voltage", self.voltage)
                .f32("current", self.current)
                .bool("charging", charging);
        });
    }
}

/// Refuses `v` above `max` as sent (-2: a value the device cannot take);
/// the `f32` to act on.
fn checked(what: &str, v: Number<'_>, max: f32) -> SimResult<f32> {
    if v.above(max) {
        let max = Number::from(max);
        return Err(SimError::Refused(format!("{what} {v} above {max}")));
    }
    Ok(v.value())
}

/// The battery management system.
#[derive(Clone, Copy, Debug)]
struct Bms {
    power: bool,
    charging: bool,
}

impl Bms {
    fn write(&self, out: &mut Fields<'_>, battery: f64) {
        out.object("bms", |o| {
            o.bool("power", self.power)
                .bool("charging", self.charging)
                .f64("battery", round1(battery));
        });
    }
}

/// The Livox lidar and its driver.
#[derive(Clone, Debug)]
struct Lidar {
    on: bool,
    driver: bool,
    last_kill_script: Option<String>,
}

impl Lidar {
    /// `lidaronoff`, `kill_livox`, `lidarwarn`.
    fn run(&mut self, args: &Args<'_>, air: Airframe, out: &mut Fields<'_>) {
        match *args {
            Args::Flag(on) => (self.on, self.driver) = (on, on),
            Args::OptName(script) => {
                self.driver = false;
                self.last_kill_script = script.map(str::to_owned);
                tracing::info!(script = script.unwrap_or("-"), "livox driver killed");
            }
            _ => return self.write_warnings(out, air),
        }
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
    fn write_warnings(&self, out: &mut Fields<'_>, air: Airframe) {
        let running = self.on && self.driver;
        out.bool("lidar_on", running);
        out.array("warn_zones", |a| {
            let level = match air.altitude {
                _ if !(running && air.airborne) => return,
                h if h < 0.3 => "alarm",
                h if h < 1.0 => "warn",
                _ => return,
            };
            a.object(|o| {
                o.str("sector", "down")
                    .f32("distance_m", air.altitude as f32)
                    .str("level", level);
            });
        });
    }
}

/// The ultrasonic thickness gauge.
#[derive(Clone, Copy, Debug)]
struct Utg {
    /// Sonic speed of the material, m/s.
    speed: f32,
    reads: u32,
}

impl Utg {
    /// Sets the sonic speed (above 0, up to [`UTG_MAX_SPEED`]).
    fn set_speed(&mut self, v: Number<'_>) -> SimResult {
        // On the f32 the gauge would use: 1e-50 is above 0, but not its f32.
        if v.value() <= 0.0 {
            return Err(SimError::Refused("UTG sonic speed must be above 0".into()));
        }
        self.speed = checked("UTG sonic speed", v, UTG_MAX_SPEED)?;
        Ok(())
    }

    /// Writes `utg`: the thickness is half the echo's round trip at the
    /// material's sonic speed.
    fn write(&self, out: &mut Fields<'_>) {
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
struct Ara8 {
    centered: bool,
    /// Pitch, degrees.
    pitch: f32,
}

impl Ara8 {
    /// `ara8_center` and `ara8_pitch`.
    fn run(&mut self, args: &Args<'_>, out: &mut Fields<'_>) {
        (self.centered, self.pitch) = match *args {
            Args::Angle(pitch) => (false, pitch),
            _ => (true, 0.0),
        };
        out.object("ara8", |o| {
            o.str("mode", if self.centered { "center" } else { "pitch" })
                .f32("pitch", self.pitch);
        });
    }
}

/// `v` rounded to one decimal, for human-facing percentages.
pub(crate) fn round1(v: f64) -> f64 {
    (v * 10.0).round() / 10.0
}
