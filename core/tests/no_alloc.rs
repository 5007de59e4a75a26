//! Handling frames allocates nothing: a counting global allocator watches
//! this thread while frames of every kind go through the server, the parser
//! and the encoder.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use lluav_core::{
    Args, Auth, Backend, Command, CommandId, Context, Failure, Fields, Message, Outcome, Server, Session,
    Step, TABLE, parse,
};

struct Counting;

thread_local! {
    static WATCHING: Cell<bool> = const { Cell::new(false) };
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

// SAFETY: defers every operation to the system allocator unchanged; it only
// counts calls made while this thread is watching.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

fn count() {
    // try_with: the thread-locals may already be gone while a thread exits.
    let _ = WATCHING.try_with(|w| {
        if w.get() {
            let _ = ALLOCATIONS.try_with(|a| a.set(a.get() + 1));
        }
    });
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by `f` on this thread.
fn allocations_during(f: impl FnOnce()) -> usize {
    ALLOCATIONS.with(|a| a.set(0));
    WATCHING.with(|w| w.set(true));
    f();
    WATCHING.with(|w| w.set(false));
    ALLOCATIONS.with(|a| a.get())
}

/// A vehicle that writes typical fields and keeps its state in place.
struct Vehicle {
    armed: bool,
    executed: usize,
}

impl Backend for Vehicle {
    fn armed(&self) -> bool {
        self.armed
    }
    fn execute(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        self.executed += 1;
        match cmd.args() {
            Args::MwExec { wp_ids, .. } => {
                out.array("wp_ids", |a| {
                    for id in wp_ids {
                        a.u64(u64::from(*id));
                    }
                });
            }
            Args::Setpoint(p) => {
                out.f32("x", p.x).f32("y", p.y).f32("z", p.z).f32("yaw", p.yaw);
            }
            _ if cmd.id() == CommandId::Sysinfo => return Err(Failure::system("sysinfo() failed")),
            _ => {
                out.object("state", |s| {
                    s.bool("armed", self.armed)
                        .str("fsm", "hover")
                        .bool("lock_mode", ctx.lock_mode);
                });
            }
        }
        Ok(Step::Done)
    }
}

fn frames() -> Vec<Vec<u8>> {
    let mut f: Vec<Vec<u8>> = [
        "login wrong",
        "login pw",
        "state",
        "set_sp_ned 1.0:2.0:-3.0:0.5",
        "mw_exec 1001:1,2,3,4,5,6,7,8,9,10",
        r#"mission 1001:{"waypoints":[{"x":1,"y":2,"z":-3},{"x":4,"y":5,"z":-6,"yaw":1.5}]}"#,
        "zyhk 1.5,2.0,2.5 0,0,0",
        "takeoff",
        "reboot_system",
        "sysinfo",
        "bogus_command with args",
        "set_sp_ned nan:0:0:0",
        "mission 1:{\"a\":",
        "",
        "help",
        "login 1025",
        "admin_lock",
        "passwd n3w",
        "admin_unlock",
    ]
    .iter()
    .map(|s| s.as_bytes().to_vec())
    .collect();
    f.push(vec![b'x'; 4000]);
    f.push(b"state \xff".to_vec());
    f
}

#[test]
fn handling_frames_allocates_nothing() {
    let mut server = Server::new(
        Vehicle {
            armed: false,
            executed: 0,
        },
        || 1_i64,
        Auth::new(Some("pw")).unwrap(),
    );
    let frames = frames();
    let mut out = vec![0u8; 64 * 1024];
    let mut small = vec![0u8; 300];
    let mut replies = 0;
    let n = allocations_during(|| {
        for round in 0..4 {
            let mut session = Session::new();
            server.backend_mut().armed = round % 2 == 1;
            for frame in &frames {
                let buf: &mut [u8] = if round == 3 { &mut small } else { &mut out };
                match server.handle(&mut session, Message::Text(frame), buf) {
                    Outcome::Reply(_) | Outcome::ReplyThenClose(..) => replies += 1,
                    Outcome::Close(_) => {}
                    Outcome::Pending(t, _) => panic!("never pends: {t:?}"),
                }
            }
            let _ = server.handle(&mut session, Message::Binary(b"x"), &mut out);
        }
    });
    assert_eq!(n, 0, "allocations while handling frames");
    assert!(replies >= 4 * (frames.len() - 1), "every text frame was answered");
    assert!(server.backend().executed > 0, "frames reached the vehicle");
}

#[test]
fn parsing_and_encoding_every_command_allocates_nothing() {
    let frames: Vec<String> = TABLE
        .iter()
        .flat_map(|s| {
            common::valid_args(s.grammar)
                .into_iter()
                .map(|a| common::frame(s.name(), &a))
        })
        .collect();
    let mut parsed = 0;
    let n = allocations_during(|| {
        for f in &frames {
            if let Ok(cmd) = parse(f) {
                let mut text: heapless::String<4200> = heapless::String::new();
                cmd.encode(&mut text).expect("fits");
                parsed += usize::from(parse(&text).is_ok());
            }
        }
    });
    assert_eq!(n, 0);
    assert_eq!(parsed, frames.len(), "every valid frame parsed and round-tripped");
}

#[test]
fn the_counter_sees_allocations() {
    let n = allocations_during(|| {
        std::hint::black_box(vec![0u8; 10]);
    });
    assert_eq!(n, 1);
}
