//! ns per frame of lluav-core against a straightforward std baseline doing
//! the same work, plus heap allocations per frame for both.
//!
//! `cargo bench -p lluav-core --bench frames` — prints criterion's figures,
//! then a table of both means and their ratio, measured in the same run.

mod baseline;
mod vehicle;
mod workload;

use std::alloc::{GlobalAlloc, Layout, System};
use std::hint::black_box;
use std::sync::atomic::{AtomicUsize, Ordering};

use baseline::{Baseline, BaselineSession};
use criterion::{Criterion, Throughput};
use lluav_core::{Auth, Message, Outcome, Server, Session};
use vehicle::Vehicle;
use workload::mix;

struct Counting;
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: defers to the system allocator unchanged; only counts calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

type CoreServer = Server<Vehicle, fn() -> i64>;

fn core_server(armed: bool) -> (CoreServer, Session) {
    let clock: fn() -> i64 = || 1_714_233_600_000;
    let mut server = Server::new(Vehicle { armed }, clock, Auth::new(Some("pw")).expect("password"));
    let mut session = Session::new();
    let mut out = [0u8; 512];
    let _ = server.handle(&mut session, Message::Text(b"login pw"), &mut out);
    (server, session)
}

fn baseline_server(armed: bool) -> (Baseline, BaselineSession) {
    let mut b = Baseline::new(Some("pw"));
    let mut s = BaselineSession::default();
    let _ = b.handle(&mut s, "login pw");
    b.armed = armed;
    (b, s)
}

fn allocations_per_frame(f: impl FnMut()) -> f64 {
    let mut f = f;
    const N: usize = 1000;
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    for _ in 0..N {
        f();
    }
    (ALLOCATIONS.load(Ordering::Relaxed) - before) as f64 / N as f64
}

fn main() {
    let mut c = Criterion::default().configure_from_args();
    let mut rows = Vec::new();
    for (label, frame, armed) in mix() {
        let (mut server, mut session) = core_server(armed);
        let mut out = vec![0u8; 64 * 1024];
        let (mut base, mut bsession) = baseline_server(armed);

        // Both must answer the frame the same way before they are timed.
        let ours = match server.handle(&mut session, Message::Text(frame.as_bytes()), &mut out) {
            Outcome::Reply(r) => serde_json::from_str::<serde_json::Value>(r).expect("json"),
            other => panic!("{label}: {other:?}"),
        };
        let theirs: serde_json::Value =
            serde_json::from_str(&base.handle(&mut bsession, &frame)).expect("json");
        assert_eq!(
            (&ours["ret"], &ours["cmd"]),
            (&theirs["ret"], &theirs["cmd"]),
            "{label}"
        );

        let core_allocs = allocations_per_frame(|| {
            let _ =
                black_box(server.handle(&mut session, Message::Text(black_box(frame.as_bytes())), &mut out));
        });
        let base_allocs = allocations_per_frame(|| {
            black_box(base.handle(&mut bsession, black_box(&frame)));
        });

        let mut g = c.benchmark_group(label);
        g.throughput(Throughput::Elements(1));
        g.bench_function("lluav-core", |b| {
            b.iter(|| {
                let o = server.handle(&mut session, Message::Text(black_box(frame.as_bytes())), &mut out);
                black_box(matches!(o, Outcome::Reply(_)));
            })
        });
        g.bench_function("std-baseline", |b| {
            b.iter(|| black_box(base.handle(&mut bsession, black_box(&frame))))
        });
        g.finish();
        rows.push((label, core_allocs, base_allocs));
    }
    c.final_summary();

    println!(
        "\n{:<20} {:>12} {:>14} {:>8} {:>13} {:>15}",
        "frame", "core ns", "baseline ns", "ratio", "core allocs", "baseline allocs"
    );
    for (label, core_allocs, base_allocs) in rows {
        let mean = |id: &str| -> Option<f64> {
            let path = format!("target/criterion/{label}/{id}/new/estimates.json");
            let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("..")
                .join(path);
            let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok()?;
            v["mean"]["point_estimate"].as_f64()
        };
        match (mean("lluav-core"), mean("std-baseline")) {
            (Some(ours), Some(theirs)) => println!(
                "{label:<20} {ours:>12.1} {theirs:>14.1} {:>7.1}x {core_allocs:>13.1} {base_allocs:>15.1}",
                theirs / ours
            ),
            _ => println!("{label:<20} (no criterion estimates found: run without --test)"),
        }
    }
}
