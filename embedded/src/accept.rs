//! The `Sec-WebSocket-Accept` value (RFC 6455, section 4.2.2): base64 of
//! the SHA-1 digest of the client's key and the protocol's GUID.
//!
//! SHA-1 is written here, small rather than fast (a handshake hashes 128
//! bytes once per connection), instead of pulling in a crate whose unrolled
//! compression function costs kilobytes of flash on a board.

/// The GUID every WebSocket server appends to the client's key.
const GUID: &[u8; 36] = b"258EAFA5-E914-47DA-95CA-C5AB0DC85B11";

/// The length of an accept value: 20 digest bytes in base64.
pub const ACCEPT_LEN: usize = 28;

/// The accept value answering `key` (the 24 characters the client sent).
pub fn accept_value(key: &[u8; 24]) -> [u8; ACCEPT_LEN] {
    let mut input = [0u8; 24 + GUID.len()];
    let (k, g) = input.split_at_mut(24);
    k.copy_from_slice(key);
    g.copy_from_slice(GUID);
    let mut out = [0u8; ACCEPT_LEN];
    base64(&sha1(&input), &mut out);
    out
}

/// The SHA-1 digest of `message` (FIPS 180-4).
pub fn sha1(message: &[u8]) -> [u8; 20] {
    let mut state: [u32; 5] = [0x6745_2301, 0xEFCD_AB89, 0x98BA_DCFE, 0x1032_5476, 0xC3D2_E1F0];
    let blocks = message.chunks_exact(64);
    let rest = blocks.remainder();
    for block in blocks {
        compress(&mut state, block);
    }
    // The tail: the remaining bytes, 0x80, zeros, and the length in bits,
    // in one block or two.
    let mut tail = [0u8; 128];
    let used = if rest.len() < 56 { 64 } else { 128 };
    if let Some(dst) = tail.get_mut(..rest.len()) {
        dst.copy_from_slice(rest);
    }
    if let Some(b) = tail.get_mut(rest.len()) {
        *b = 0x80;
    }
    let bits = (message.len() as u64).wrapping_mul(8);
    if let Some(dst) = tail.get_mut(used - 8..used) {
        dst.copy_from_slice(&bits.to_be_bytes());
    }
    for block in tail.chunks_exact(64).take(used / 64) {
        compress(&mut state, block);
    }
    let mut digest = [0u8; 20];
    for (dst, word) in digest.chunks_exact_mut(4).zip(state) {
        dst.copy_from_slice(&word.to_be_bytes());
    }
    digest
}

/// One 64-byte block into the state. The message schedule is kept as a
/// sliding window of 16 words: `w[0]` is the current round's word.
fn compress(state: &mut [u32; 5], block: &[u8]) {
    let mut w = [0u32; 16];
    for (word, bytes) in w.iter_mut().zip(block.chunks_exact(4)) {
        *word = bytes.iter().fold(0, |acc, &b| acc << 8 | u32::from(b));
    }
    let [mut a, mut b, mut c, mut d, mut e] = *state;
    for round in 0..80 {
        let (f, k) = match round {
            0..=19 => ((b & c) | (!b & d), 0x5A82_7999),
            20..=39 => (b ^ c ^ d, 0x6ED9_EBA1),
            40..=59 => ((b & c) | (b & d) | (c & d), 0x8F1B_BCDC),
            _ => (b ^ c ^ d, 0xCA62_C1D6),
        };
        let t = a
            .rotate_left(5)
            .wrapping_add(f)
            .wrapping_add(e)
            .wrapping_add(k)
            .wrapping_add(w[0]);
        (e, d, c, b, a) = (d, c, b.rotate_left(30), a, t);
        let next = (w[13] ^ w[8] ^ w[2] ^ w[0]).rotate_left(1);
        w.copy_within(1.., 0);
        w[15] = next;
    }
    for (s, v) in state.iter_mut().zip([a, b, c, d, e]) {
        *s = s.wrapping_add(v);
    }
}

/// Standard base64 with padding; `out` must hold `4 * ceil(len / 3)` bytes
/// (what does not fit is left out).
fn base64(input: &[u8], out: &mut [u8]) {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    for (chunk, dst) in input.chunks(3).zip(out.chunks_mut(4)) {
        let n = chunk
            .iter()
            .chain([0, 0].iter())
            .take(3)
            .fold(0u32, |acc, &b| acc << 8 | u32::from(b));
        for (i, d) in dst.iter_mut().enumerate() {
            *d = if i <= chunk.len() {
                let sextet = (n >> (18 - 6 * i)) & 0x3f;
                ALPHABET.get(sextet as usize).copied().unwrap_or(b'=')
            } else {
                b'='
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(bytes: &[u8]) -> std::string::String {
        bytes.iter().map(|b| std::format!("{b:02x}")).collect()
    }

    extern crate std;

    #[test]
    fn answers_the_rfc_6455_example_key() {
        assert_eq!(
            &accept_value(b"dGhlIHNhbXBsZSBub25jZQ=="),
            b"s3pPLMBiTxaQ9kYGzzhZRbK+xOo="
        );
    }

    #[test]
    fn sha1_matches_the_fips_examples() {
        assert_eq!(hex(&sha1(b"abc")), "a9993e364706816aba3e25717850c26c9cd0d89d");
        assert_eq!(hex(&sha1(b"")), "da39a3ee5e6b4b0d3255bfef95601890afd80709");
        assert_eq!(
            hex(&sha1(b"abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq")),
            "84983e441c3bd26ebaae4aa1f95129e5e54670f1"
        );
    }

    #[test]
    fn sha1_handles_every_tail_length() {
        // Lengths around the one- and two-block padding boundaries, checked
        // against a digest computed by the `sha1` crate.
        use sha1_reference::Digest;
        let data: std::vec::Vec<u8> = (0..300u32).map(|i| (i * 7 + 3) as u8).collect();
        for len in 0..data.len() {
            let expected = sha1_reference::Sha1::digest(&data[..len]);
            assert_eq!(sha1(&data[..len])[..], expected[..], "length {len}");
        }
    }

    #[test]
    fn base64_pads_one_and_two_byte_tails() {
        let mut out = [0u8; 8];
        base64(b"ab", &mut out[..4]);
        assert_eq!(&out[..4], b"YWI=");
        base64(b"a", &mut out[..4]);
        assert_eq!(&out[..4], b"YQ==");
        base64(b"abcdef", &mut out);
        assert_eq!(&out, b"YWJjZGVm");
    }
}
