use lluav_core::number::{format_f32, parse_f32};
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let step: u32 = args.get(1).map(|s| s.parse().unwrap()).unwrap_or(1);
    let start: u64 = args.get(2).map(|s| s.parse().unwrap()).unwrap_or(0);
    let end: u64 = args.get(3).map(|s| s.parse().unwrap()).unwrap_or(1 << 32);
    let mut bad = 0u64;
    let mut buf = ryu::Buffer::new();
    let mut b = start;
    while b < end {
        let v = f32::from_bits(b as u32);
        let ours = format_f32(v);
        let theirs = if v.is_finite() { buf.format_finite(v) } else { buf.format(v) };
        if ours.as_str() != theirs {
            bad += 1;
            if bad < 20 { println!("format {:#x}: ours {} ryu {}", b, ours.as_str(), theirs); }
        }
        if v.is_finite() {
            let back = parse_f32(theirs);
            if back.map(f32::to_bits) != Some(v.to_bits()) {
                bad += 1;
                if bad < 40 { println!("parse {:?}: ours {:?} want {:#x}", theirs, back.map(f32::to_bits), b); }
            }
        }
        b += u64::from(step);
    }
    println!("bad {bad}");
}
