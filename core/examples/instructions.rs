//! Runs one frame of the benchmark mix N times through lluav-core or the
//! std baseline, for counting instructions with callgrind, which counts the
//! same on a busy machine as on an idle one. `scripts/instructions.sh`
//! drives it and prints instructions per frame and their ratio.
//!
//! ```text
//! instructions --list
//! instructions core|baseline LABEL N
//! ```

#[path = "../benches/frames/baseline.rs"]
mod baseline;
#[path = "../benches/frames/vehicle.rs"]
mod vehicle;
#[path = "../benches/frames/workload.rs"]
mod workload;

use std::hint::black_box;

use lluav_core::{Auth, Message, Server, Session};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mix = workload::mix();
    if args.first().map(String::as_str) == Some("--list") {
        for (label, _, _) in &mix {
            println!("{label}");
        }
        return;
    }
    let (which, label, n) = match args.as_slice() {
        [w, l, n] => (w.as_str(), l.as_str(), n.parse::<usize>().expect("N is a count")),
        _ => {
            eprintln!("usage: instructions --list | instructions core|baseline LABEL N");
            std::process::exit(2);
        }
    };
    let Some((_, frame, armed)) = mix.iter().find(|(l, _, _)| *l == label) else {
        eprintln!("unknown label {label}; see --list");
        std::process::exit(2);
    };
    match which {
        "core" => {
            let clock: fn() -> i64 = || 1_714_233_600_000;
            let vehicle = vehicle::Vehicle { armed: *armed };
            let mut server = Server::new(vehicle, clock, Auth::new(Some("pw")).expect("password"));
            let mut session = Session::new();
            let mut out = vec![0u8; 64 * 1024];
            let _ = server.handle(&mut session, Message::Text(b"login pw"), &mut out);
            for _ in 0..n {
                let _ = black_box(server.handle(
                    &mut session,
                    Message::Text(black_box(frame.as_bytes())),
                    &mut out,
                ));
            }
        }
        "baseline" => {
            let mut base = baseline::Baseline::new(Some("pw"));
            let mut session = baseline::BaselineSession::default();
            let _ = base.handle(&mut session, "login pw");
            base.armed = *armed;
            for _ in 0..n {
                black_box(base.handle(&mut session, black_box(frame)));
            }
        }
        other => {
            eprintln!("unknown implementation {other}: core or baseline");
            std::process::exit(2);
        }
    }
}
