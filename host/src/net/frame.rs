//! Server frames appended to a session's outbox. The frame rules
//! themselves (headers, masks, UTF-8 as text arrives) are the core's
//! [`lluav_core::websocket`], shared with the embedded adapter.

use lluav_core::websocket::{MAX_SERVER_HEADER, Opcode, write_header};

/// Appends a final (FIN), unmasked server frame with `payload` to `out`.
pub fn write(out: &mut Vec<u8>, opcode: Opcode, payload: &[u8]) {
    // The longest server header fits `header`, so nothing is ever cut.
    let mut header = [0; MAX_SERVER_HEADER];
    let n = write_header(&mut header, opcode, payload.len()).unwrap_or(0);
    out.reserve(n + payload.len());
    out.extend_from_slice(header.get(..n).unwrap_or_default());
    out.extend_from_slice(payload);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_is_its_header_then_its_payload() {
        let mut out = b"queued".to_vec();
        write(&mut out, Opcode::Pong, b"hi");
        write(&mut out, Opcode::Text, &[b'x'; 126]);
        assert_eq!(out[..10], *b"queued\x8a\x02hi");
        assert_eq!(out[10..14], [0x81, 126, 0, 126]);
        assert_eq!(out.len(), 14 + 126);
    }
}
