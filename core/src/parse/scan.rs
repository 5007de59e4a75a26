//! Finding an ASCII byte in text eight bytes at a time: frame names, field
//! separators. Cutting text at an ASCII byte always leaves whole
//! characters on both sides.

const ONES: u64 = 0x0101_0101_0101_0101;
const HIGH: u64 = 0x8080_8080_8080_8080;

/// The index of the first `needle` in `bytes`.
pub(crate) fn find(bytes: &[u8], needle: u8) -> Option<usize> {
    let pattern = ONES * u64::from(needle);
    let mut chunks = bytes.chunks_exact(8);
    let mut offset = 0;
    for chunk in &mut chunks {
        if let Some(word) = chunk.first_chunk::<8>() {
            let x = u64::from_le_bytes(*word) ^ pattern;
            // The lowest set bit marks the first zero byte exactly (a
            // borrow can only mark bytes above a zero one).
            let zeros = x.wrapping_sub(ONES) & !x & HIGH;
            if zeros != 0 {
                return Some(offset + (zeros.trailing_zeros() / 8) as usize);
            }
        }
        offset += 8;
    }
    let at = chunks.remainder().iter().position(|&b| b == needle)?;
    Some(offset + at)
}

/// `text` up to its `needle`s: the text before the first one and the text
/// after it, or the whole text and `None`.
pub(crate) fn cut(text: &str, needle: u8) -> (&str, Option<&str>) {
    match find(text.as_bytes(), needle) {
        Some(at) => (text.get(..at).unwrap_or_default(), text.get(at + 1..)),
        None => (text, None),
    }
}
