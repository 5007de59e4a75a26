use lluav_core::number::{format_f32, parse_f32};
use std::hint::black_box;
fn main() {
    let which = std::env::args().nth(1).unwrap();
    let n: usize = std::env::args().nth(2).unwrap().parse().unwrap();
    let nice = [1.5f32, -2.25, -10.0, 0.0, 0.5, 87.5, 3.0, 100.0];
    let general = [0.1f32, 0.3, 12.345, -47.123456, 1e-7, 3.3, 0.7, 123456.79];
    let texts = ["1.0", "2.0", "-3.0", "0.5"];
    let long = ["12.345678", "0.123456789", "-47.1234567", "3.14159265358979"];
    let mut acc = 0usize;
    for _ in 0..n {
        match which.as_str() {
            "nice" => { for v in nice { acc += format_f32(black_box(v)).as_bytes().len(); } }
            "general" => { for v in general { acc += format_f32(black_box(v)).as_bytes().len(); } }
            "ryu" => { for v in general { acc += ryu::Buffer::new().format_finite(black_box(v)).len(); } }
            "parse" => { for t in texts { acc += parse_f32(black_box(t)).unwrap() as usize; } }
            "std" => { for t in texts { acc += black_box(t).parse::<f32>().unwrap() as usize; } }
            "parselong" => { for t in long { acc += parse_f32(black_box(t)).unwrap() as usize; } }
            "stdlong" => { for t in long { acc += black_box(t).parse::<f32>().unwrap() as usize; } }
            _ => {}
        }
    }
    println!("{acc}");
}
