//! The backend of a companion board without an autopilot link: it drives
//! what the board has (a user LED and a PWM output), reports the armed
//! state the firmware feeds it, and answers every other command as
//! unsupported (ret -2), honestly.

use lluav_core::{Args, Backend, Command, CommandId, Context, Failure, Fields, Step};

/// What the user LED should do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Led {
    /// Dark.
    Off,
    /// Lit.
    On,
    /// Blinking (the firmware's LED task keeps the rhythm).
    Blink,
}

impl Led {
    /// The name `state` reports.
    pub fn name(self) -> &'static str {
        match self {
            Led::Off => "off",
            Led::On => "on",
            Led::Blink => "blink",
        }
    }
}

/// The peripherals a board wires to the protocol.
pub trait Peripherals {
    /// Shows `mode` on the user LED.
    fn led(&mut self, mode: Led);
    /// Sets the PWM output's duty cycle, `duty`/65535 of the period.
    fn pwm(&mut self, duty: u16) -> Result<(), Failure>;
}

/// The answer to LED commands while LED control is disabled.
pub const LED_DISABLED: &str = "LED control is disabled";

/// The answer to every command this board cannot carry out.
pub const UNSUPPORTED: &str = "Not supported on this board";

/// A [`Backend`] for a board with a user LED and a PWM output.
#[derive(Debug)]
pub struct Board<P> {
    peripherals: P,
    armed: bool,
    led_enabled: bool,
    led: Led,
    pwm: u16,
}

impl<P: Peripherals> Board<P> {
    /// A disarmed board with LED control enabled and the LED off.
    pub fn new(mut peripherals: P) -> Self {
        peripherals.led(Led::Off);
        Board {
            peripherals,
            armed: false,
            led_enabled: true,
            led: Led::Off,
            pwm: 0,
        }
    }

    /// Records the vehicle's armed state, as the firmware reads it (e.g.
    /// from the autopilot's armed line).
    pub fn set_armed(&mut self, armed: bool) {
        self.armed = armed;
    }

    /// The peripherals.
    pub fn peripherals(&self) -> &P {
        &self.peripherals
    }

    fn set_led(&mut self, mode: Led) -> Result<(), Failure> {
        if !self.led_enabled {
            return Err(Failure::failed(LED_DISABLED));
        }
        self.led = mode;
        self.peripherals.led(mode);
        Ok(())
    }
}

impl<P: Peripherals> Backend for Board<P> {
    fn armed(&self) -> bool {
        self.armed
    }

    fn execute(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        match (cmd.id(), cmd.args()) {
            (CommandId::State, _) => {
                let (armed, led, enabled, pwm) = (self.armed, self.led, self.led_enabled, self.pwm);
                out.object("state", |s| {
                    s.bool("armed", armed)
                        .str("fsm", if armed { "armed" } else { "disarmed" })
                        .bool("lock_mode", ctx.lock_mode)
                        .str("led", led.name())
                        .bool("led_enabled", enabled)
                        .u64("led_pwm", u64::from(pwm));
                    ctx.write_authority(s);
                });
                Ok(Step::Done)
            }
            (CommandId::Ledon, _) => self.set_led(Led::On).map(|()| Step::Done),
            (CommandId::Ledoff, _) => self.set_led(Led::Off).map(|()| Step::Done),
            (CommandId::LedBlink, _) => self.set_led(Led::Blink).map(|()| Step::Done),
            (CommandId::Ledenable, _) => {
                self.led_enabled = true;
                Ok(Step::Done)
            }
            (CommandId::Leddisable, _) => {
                self.led_enabled = false;
                self.led = Led::Off;
                self.peripherals.led(Led::Off);
                Ok(Step::Done)
            }
            (CommandId::Ledpwm, Args::Pwm(duty)) => {
                if !self.led_enabled {
                    return Err(Failure::failed(LED_DISABLED));
                }
                self.peripherals.pwm(*duty)?;
                self.pwm = *duty;
                out.u64("pwm", u64::from(*duty));
                Ok(Step::Done)
            }
            _ => Err(Failure::unsupported(UNSUPPORTED)),
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;

    use std::vec::Vec;

    use lluav_core::{Auth, Message, Outcome, Server, Session};

    use super::*;

    #[derive(Default)]
    struct Recorder {
        leds: Vec<Led>,
        pwm: Vec<u16>,
    }

    impl Peripherals for Recorder {
        fn led(&mut self, mode: Led) {
            self.leds.push(mode);
        }
        fn pwm(&mut self, duty: u16) -> Result<(), Failure> {
            self.pwm.push(duty);
            Ok(())
        }
    }

    fn call(server: &mut Server<Board<Recorder>, fn() -> i64>, frame: &str) -> serde_json::Value {
        let mut session = Session::new();
        let mut out = [0u8; 2048];
        match server.handle(&mut session, Message::Text(frame.as_bytes()), &mut out) {
            Outcome::Reply(r) => serde_json::from_str(r).unwrap(),
            other => panic!("{other:?}"),
        }
    }

    fn board() -> Server<Board<Recorder>, fn() -> i64> {
        Server::new(
            Board::new(Recorder::default()),
            (|| 0) as fn() -> i64,
            Auth::new(None).unwrap(),
        )
    }

    #[test]
    fn led_commands_drive_the_led_and_pwm() {
        let mut s = board();
        for frame in ["ledon", "led_blink", "ledoff", "ledpwm 32768"] {
            assert_eq!(call(&mut s, frame)["ret"], 0, "{frame}");
        }
        let p = s.backend().peripherals();
        assert_eq!(p.leds, [Led::Off, Led::On, Led::Blink, Led::Off]);
        assert_eq!(p.pwm, [32768]);
        assert_eq!(call(&mut s, "state")["state"]["led_pwm"], 32768);
    }

    #[test]
    fn disabled_led_control_refuses_led_commands() {
        let mut s = board();
        assert_eq!(call(&mut s, "leddisable")["ret"], 0);
        let r = call(&mut s, "ledon");
        assert_eq!(
            (r["ret"].as_i64(), r["msg"].as_str()),
            (Some(-1), Some(LED_DISABLED))
        );
        assert_eq!(call(&mut s, "ledpwm 1")["ret"], -1);
        assert_eq!(call(&mut s, "ledenable")["ret"], 0);
        assert_eq!(call(&mut s, "ledon")["ret"], 0);
    }

    #[test]
    fn armed_state_comes_from_the_firmware() {
        let mut s = board();
        s.backend_mut().set_armed(true);
        assert_eq!(call(&mut s, "state")["state"]["armed"], true);
        assert_eq!(
            call(&mut s, "reboot_system")["msg"],
            "Not allow when vehicle is ARMED!"
        );
    }

    #[test]
    fn commands_the_board_cannot_do_are_unsupported() {
        let mut s = board();
        for frame in ["takeoff", "sysinfo", "set_sp_ned 1:2:-3:0"] {
            let r = call(&mut s, frame);
            assert_eq!(
                (r["ret"].as_i64(), r["msg"].as_str()),
                (Some(-2), Some(UNSUPPORTED)),
                "{frame}"
            );
        }
    }
}
