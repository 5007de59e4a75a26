use lluav_core::number::parse_f32;
/// Decimal digits of c · 2^a · 5^b (a, b >= 0) as a string.
fn digits(c: u64, a: u32, b: u32) -> String {
    let mut limbs: Vec<u64> = vec![c]; // base 1e9
    let base = 1_000_000_000u64;
    let mut norm = |limbs: &mut Vec<u64>| { let mut carry = 0; for l in limbs.iter_mut() { let t = *l + carry; *l = t % base; carry = t / base; } while carry > 0 { limbs.push(carry % base); carry /= base; } };
    norm(&mut limbs);
    for _ in 0..a { for l in limbs.iter_mut() { *l *= 2; } norm(&mut limbs); }
    for _ in 0..b { for l in limbs.iter_mut() { *l *= 5; } norm(&mut limbs); }
    let mut s = limbs.last().unwrap().to_string();
    for l in limbs.iter().rev().skip(1) { s.push_str(&format!("{l:09}")); }
    s
}
/// Exact decimal text of (2c+1) · 2^(q-1).
fn midpoint(c: u64, q: i32) -> String {
    let m = 2 * c + 1;
    let e = q - 1;
    if e >= 0 { digits(m, e as u32, 0) } else { let d = digits(m, 0, (-e) as u32); format!("{d}e{e}") }
}
fn main() {
    let step: u32 = std::env::args().nth(1).map(|s| s.parse().unwrap()).unwrap_or(1000);
    let mut bad = 0; let mut n = 0;
    let mut b: u64 = 0;
    while b < 0x7F80_0000 {
        let bits = b as u32;
        let (c, q) = if bits >> 23 == 0 { (u64::from(bits), -149) } else { (u64::from(bits & 0x7FFFFF | 1 << 23), (bits >> 23) as i32 - 150) };
        let mid = midpoint(c, q);
        // exact, slightly above, slightly below
        let (m, e) = match mid.split_once('e') { Some((m, e)) => (m.to_string(), format!("e{e}")), None => (mid.clone(), String::new()) };
        let above = format!("{m}.00000000000000000000000000001{e}");
        let below = { let mut d: Vec<u8> = m.clone().into_bytes(); let mut i = d.len(); loop { i -= 1; if d[i] == b'0' { d[i] = b'9'; } else { d[i] -= 1; break; } } format!("{}.9999999999999999999999{e}", String::from_utf8(d).unwrap()) };
        for s in [&mid, &above, &below] {
            n += 1;
            let ours = parse_f32(s); let theirs: f32 = s.parse().unwrap();
            if ours.map(f32::to_bits) != Some(theirs.to_bits()) { bad += 1; if bad < 20 { println!("{s}: ours {ours:?} std {theirs:?}"); } }
        }
        b += u64::from(step);
    }
    println!("bad {bad} of {n}");
}
