use lluav_core::number::parse_f32;
struct Rng(u64);
impl Rng { fn next(&mut self) -> u64 { self.0 = self.0.wrapping_add(0x9E3779B97F4A7C15); let mut z = self.0; z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9); z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB); z ^ (z >> 31) } fn below(&mut self, n: u64) -> u64 { self.next() % n } }
fn main() {
    let n: u64 = std::env::args().nth(1).map(|s| s.parse().unwrap()).unwrap_or(1_000_000);
    let mut rng = Rng(42);
    let mut bad = 0;
    let mut s = String::new();
    for i in 0..n {
        s.clear();
        if rng.below(2) == 0 { s.push('-'); }
        let ndig = match rng.below(4) { 0 => 1 + rng.below(8), 1 => 1 + rng.below(20), 2 => 1 + rng.below(40), _ => 1 + rng.below(200) } as usize;
        let point = rng.below(ndig as u64 + 2) as usize;
        let lead_zeros = if rng.below(4) == 0 { rng.below(50) as usize } else { 0 };
        for _ in 0..lead_zeros { s.push('0'); }
        for j in 0..ndig { if j == point { s.push('.'); } let d = if rng.below(5) == 0 { b'0' } else if rng.below(9)==0 { b'9' } else { b'0' + rng.below(10) as u8 }; s.push(d as char); }
        if rng.below(2) == 0 { s.push('e'); let e = match rng.below(3) { 0 => rng.below(20) as i64 - 10, 1 => rng.below(120) as i64 - 60, _ => rng.below(500) as i64 - 250 }; s.push_str(&e.to_string()); }
        let ours = parse_f32(&s);
        let theirs: f32 = s.parse().unwrap();
        if ours.map(f32::to_bits) != Some(theirs.to_bits()) { bad += 1; if bad < 20 { println!("{i}: {s:?} ours {ours:?} std {theirs:?}"); } }
    }
    println!("bad {bad} of {n}");
}
