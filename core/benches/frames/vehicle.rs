//! The benchmark vehicle: the same answers the std baseline writes. It
//! uses lluav-core alone (no std), so the Cortex-M firmware in
//! `embedded/core-only` includes this very file and its instruction counts
//! are of the same work.

use lluav_core::{Args, Backend, Command, Context, Failure, Fields, Payload, Step};

/// The same vehicle answers as the baseline's: a 12-field state, setpoint
/// echo, waypoint ids, mission waypoint count.
pub struct Vehicle {
    pub armed: bool,
}

impl Backend for Vehicle {
    fn armed(&self) -> bool {
        self.armed
    }
    fn execute(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        match cmd.args() {
            Args::None => {
                out.object("state", |s| {
                    s.bool("armed", self.armed)
                        .str("fsm", "hover")
                        .bool("lock_mode", ctx.lock_mode)
                        .f32("x", 1.5)
                        .f32("y", -2.25)
                        .f32("z", -10.0)
                        .f32("vx", 0.0)
                        .f32("vy", 0.1)
                        .f32("vz", 0.0)
                        .f32("yaw", 0.5)
                        .f32("battery", 87.5);
                });
            }
            Args::Setpoint(p) => {
                out.f32("x", p.x).f32("y", p.y).f32("z", p.z).f32("yaw", p.yaw);
            }
            Args::MwExec { ext_id, wp_ids } => {
                out.u64("ext_id", u64::from(*ext_id)).array("wp_ids", |a| {
                    for id in wp_ids {
                        a.u64(u64::from(*id));
                    }
                });
            }
            Args::Mission { ext_id, payload } => {
                let n = match payload {
                    Payload::Json(j) => waypoints(j),
                    Payload::Path(_) => 0,
                };
                out.u64("waypoints", n as u64).u64("ext_id", u64::from(*ext_id));
            }
            _ => {}
        }
        Ok(Step::Done)
    }
}

/// The waypoints of a benchmark mission: one `"x"` key each. The x bytes
/// are found eight at a time (`str::matches` builds a two-way searcher per
/// call and costs several instructions per byte, all of which would be
/// counted as the core's).
fn waypoints(json: &str) -> usize {
    const ONES: u64 = 0x0101_0101_0101_0101;
    let bytes = json.as_bytes();
    let key_at = |i: usize| {
        i > 0
            && bytes.get(i - 1) == Some(&b'"')
            && bytes.get(i) == Some(&b'x')
            && bytes.get(i + 1) == Some(&b'"')
    };
    let mut n = 0;
    let mut chunks = bytes.chunks_exact(8);
    for (c, chunk) in (&mut chunks).enumerate() {
        let mut word = [0; 8];
        word.copy_from_slice(chunk);
        let x = u64::from_le_bytes(word) ^ (ONES * u64::from(b'x'));
        // A high bit for each zero byte (and possibly some above one: the
        // candidates are checked byte by byte).
        let mut candidates = x.wrapping_sub(ONES) & !x & (ONES << 7);
        while candidates != 0 {
            n += usize::from(key_at(c * 8 + (candidates.trailing_zeros() / 8) as usize));
            candidates &= candidates - 1;
        }
    }
    let tail = bytes.len() - chunks.remainder().len();
    n + (tail..bytes.len()).filter(|&i| key_at(i)).count()
}
