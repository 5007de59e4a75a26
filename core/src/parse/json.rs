//! A JSON well-formedness check (RFC 8259) that allocates nothing and uses
//! no recursion: nesting is tracked in a fixed bit stack, so a hostile
//! payload can neither exhaust memory nor overflow the call stack.
//!
//! One pass over the bytes with a cursor; the end of the text reads as a
//! NUL byte, which is invalid everywhere in JSON (outside strings it starts
//! no token, inside them it is a control character), so running off the end
//! needs no check of its own.

use crate::error::ArgError;

/// Deepest nesting of objects and arrays a payload may use.
pub const MAX_JSON_DEPTH: usize = 64;

/// Open containers, innermost in bit 0: 1 = object, 0 = array.
struct Stack {
    bits: u64,
    depth: usize,
}

impl Stack {
    fn push(&mut self, object: bool) -> Option<()> {
        if self.depth == MAX_JSON_DEPTH {
            return None;
        }
        self.bits = (self.bits << 1) | u64::from(object);
        self.depth += 1;
        Some(())
    }

    fn pop(&mut self) {
        self.bits >>= 1;
        self.depth -= 1;
    }

    fn in_object(&self) -> bool {
        self.depth > 0 && self.bits & 1 == 1
    }

    fn in_array(&self) -> bool {
        self.depth > 0 && self.bits & 1 == 0
    }
}

struct Scanner<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl Scanner<'_> {
    /// The byte at the cursor; 0 at the end.
    #[inline]
    fn peek(&self) -> u8 {
        self.bytes.get(self.pos).copied().unwrap_or(0)
    }

    #[inline]
    fn skip_ws(&mut self) {
        while matches!(self.peek(), b' ' | b'\t' | b'\n' | b'\r') {
            self.pos += 1;
        }
    }

    fn literal(&mut self, word: &[u8]) -> Option<()> {
        let end = self.pos + word.len();
        (self.bytes.get(self.pos..end)? == word).then(|| self.pos = end)
    }

    /// Digits at the cursor; whether there was at least one.
    #[inline]
    fn digits(&mut self) -> bool {
        let start = self.pos;
        while self.peek().is_ascii_digit() {
            self.pos += 1;
        }
        self.pos > start
    }

    fn number(&mut self) -> Option<()> {
        if self.peek() == b'-' {
            self.pos += 1;
        }
        match self.peek() {
            b'0' => self.pos += 1,
            b'1'..=b'9' => {
                self.digits();
            }
            _ => return None,
        }
        if self.peek() == b'.' {
            self.pos += 1;
            self.digits().then_some(())?;
        }
        if matches!(self.peek(), b'e' | b'E') {
            self.pos += 1;
            if matches!(self.peek(), b'+' | b'-') {
                self.pos += 1;
            }
            self.digits().then_some(())?;
        }
        Some(())
    }

    /// A string at the cursor, quotes included. The input is `&str`, so
    /// the bytes are valid UTF-8 already; only escapes and control bytes
    /// need checks. (Byte by byte: keys are short, a word at a time would
    /// cost more than it saves.)
    fn string(&mut self) -> Option<()> {
        if self.peek() != b'"' {
            return None;
        }
        self.pos += 1;
        loop {
            let b = self.peek();
            self.pos += 1;
            match b {
                b'"' => return Some(()),
                b'\\' => self.escape()?,
                0x00..=0x1f => return None,
                _ => {}
            }
        }
    }

    /// The rest of an escape, after its backslash.
    fn escape(&mut self) -> Option<()> {
        let escape = self.peek();
        self.pos += 1;
        match escape {
            b'"' | b'\\' | b'/' | b'b' | b'f' | b'n' | b'r' | b't' => Some(()),
            b'u' => {
                let hex = self.bytes.get(self.pos..self.pos + 4)?;
                hex.iter().all(u8::is_ascii_hexdigit).then_some(())?;
                self.pos += 4;
                Some(())
            }
            _ => None,
        }
    }

    /// An object key and its colon; the value follows.
    fn key(&mut self) -> Option<()> {
        self.string()?;
        self.skip_ws();
        (self.peek() == b':').then(|| self.pos += 1)
    }

    /// One value with its nested values, then nothing but whitespace.
    fn document(&mut self) -> Option<()> {
        let mut stack = Stack { bits: 0, depth: 0 };
        let mut need_value = true;
        loop {
            if need_value {
                self.skip_ws();
                match self.peek() {
                    open @ (b'{' | b'[') => {
                        self.pos += 1;
                        let object = open == b'{';
                        stack.push(object)?;
                        self.skip_ws();
                        if self.peek() == open + 2 {
                            // `{}` or `[]`: the closer is two code points on.
                            self.pos += 1;
                            stack.pop();
                        } else {
                            if object {
                                self.key()?;
                            }
                            continue;
                        }
                    }
                    b'"' => self.string()?,
                    b't' => self.literal(b"true")?,
                    b'f' => self.literal(b"false")?,
                    b'n' => self.literal(b"null")?,
                    _ => self.number()?,
                }
                need_value = false;
            }
            // After a value.
            self.skip_ws();
            match self.peek() {
                b',' if stack.depth > 0 => {
                    self.pos += 1;
                    if stack.in_object() {
                        self.skip_ws();
                        self.key()?;
                    }
                    need_value = true;
                }
                b'}' if stack.in_object() => {
                    self.pos += 1;
                    stack.pop();
                }
                b']' if stack.in_array() => {
                    self.pos += 1;
                    stack.pop();
                }
                _ => return (stack.depth == 0 && self.pos == self.bytes.len()).then_some(()),
            }
        }
    }
}

/// Checks that `s` is exactly one well-formed JSON value, surrounded by
/// optional whitespace.
pub fn validate(s: &str) -> Result<(), ArgError> {
    let mut scanner = Scanner {
        bytes: s.as_bytes(),
        pos: 0,
    };
    scanner.document().ok_or(ArgError::BadJson)
}
