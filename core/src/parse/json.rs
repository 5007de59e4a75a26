//! A JSON well-formedness check (RFC 8259) that allocates nothing and uses
//! no recursion: nesting is tracked in a fixed bit stack, so a hostile
//! payload can neither exhaust memory nor overflow the call stack.

use crate::error::ArgError;

/// Deepest nesting of objects and arrays a payload may use.
pub const MAX_JSON_DEPTH: usize = 64;

/// Where the scanner is in the grammar.
#[derive(Clone, Copy)]
enum Expect {
    /// A value.
    Value,
    /// What may follow a complete value: `,`, a closing bracket, or the end.
    AfterValue,
}

/// Open containers, innermost in bit 0: 1 = object, 0 = array.
struct Stack {
    bits: u64,
    depth: usize,
}

impl Stack {
    fn push(&mut self, object: bool) -> Result<(), ArgError> {
        if self.depth == MAX_JSON_DEPTH {
            return Err(ArgError::BadJson);
        }
        self.bits = (self.bits << 1) | u64::from(object);
        self.depth += 1;
        Ok(())
    }

    fn pop(&mut self, object: bool) -> Result<(), ArgError> {
        if self.depth == 0 || self.in_object() != object {
            return Err(ArgError::BadJson);
        }
        self.bits >>= 1;
        self.depth -= 1;
        Ok(())
    }

    fn in_object(&self) -> bool {
        self.depth > 0 && self.bits & 1 == 1
    }
}

struct Scanner<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl Scanner<'_> {
    fn peek(&self) -> Option<u8> {
        self.bytes.get(self.pos).copied()
    }

    fn bump(&mut self) -> Option<u8> {
        let b = self.peek()?;
        self.pos += 1;
        Some(b)
    }

    fn eat(&mut self, want: u8) -> Result<(), ArgError> {
        if self.bump() == Some(want) {
            Ok(())
        } else {
            Err(ArgError::BadJson)
        }
    }

    fn skip_ws(&mut self) {
        while matches!(self.peek(), Some(b' ' | b'\t' | b'\n' | b'\r')) {
            self.pos += 1;
        }
    }

    fn literal(&mut self, word: &[u8]) -> Result<(), ArgError> {
        word.iter().try_for_each(|&b| self.eat(b))
    }

    fn digits(&mut self) -> usize {
        let start = self.pos;
        while matches!(self.peek(), Some(b'0'..=b'9')) {
            self.pos += 1;
        }
        self.pos - start
    }

    fn number(&mut self) -> Result<(), ArgError> {
        if self.peek() == Some(b'-') {
            self.pos += 1;
        }
        match self.peek() {
            Some(b'0') => self.pos += 1,
            Some(b'1'..=b'9') => {
                self.digits();
            }
            _ => return Err(ArgError::BadJson),
        }
        if self.peek() == Some(b'.') {
            self.pos += 1;
            if self.digits() == 0 {
                return Err(ArgError::BadJson);
            }
        }
        if matches!(self.peek(), Some(b'e' | b'E')) {
            self.pos += 1;
            if matches!(self.peek(), Some(b'+' | b'-')) {
                self.pos += 1;
            }
            if self.digits() == 0 {
                return Err(ArgError::BadJson);
            }
        }
        Ok(())
    }

    /// A string, opening quote included. The input is `&str`, so the bytes
    /// are valid UTF-8 already; only escapes and control bytes need checks.
    fn string(&mut self) -> Result<(), ArgError> {
        self.eat(b'"')?;
        loop {
            match self.bump().ok_or(ArgError::BadJson)? {
                b'"' => return Ok(()),
                b'\\' => match self.bump().ok_or(ArgError::BadJson)? {
                    b'"' | b'\\' | b'/' | b'b' | b'f' | b'n' | b'r' | b't' => {}
                    b'u' => {
                        for _ in 0..4 {
                            if !self.bump().ok_or(ArgError::BadJson)?.is_ascii_hexdigit() {
                                return Err(ArgError::BadJson);
                            }
                        }
                    }
                    _ => return Err(ArgError::BadJson),
                },
                0x00..=0x1f => return Err(ArgError::BadJson),
                _ => {}
            }
        }
    }

    /// An object key and its colon; the value follows.
    fn key(&mut self) -> Result<(), ArgError> {
        self.string()?;
        self.skip_ws();
        self.eat(b':')
    }
}

/// Checks that `s` is exactly one well-formed JSON value, surrounded by
/// optional whitespace.
pub fn validate(s: &str) -> Result<(), ArgError> {
    let mut sc = Scanner {
        bytes: s.as_bytes(),
        pos: 0,
    };
    let mut stack = Stack { bits: 0, depth: 0 };
    let mut expect = Expect::Value;
    loop {
        sc.skip_ws();
        expect = match expect {
            Expect::Value => match sc.peek().ok_or(ArgError::BadJson)? {
                open @ (b'{' | b'[') => {
                    sc.pos += 1;
                    stack.push(open == b'{')?;
                    sc.skip_ws();
                    match (open, sc.peek()) {
                        (b'{', Some(b'}')) | (b'[', Some(b']')) => {
                            sc.pos += 1;
                            stack.pop(open == b'{')?;
                            Expect::AfterValue
                        }
                        (b'{', _) => {
                            sc.key()?;
                            Expect::Value
                        }
                        _ => Expect::Value,
                    }
                }
                b'"' => {
                    sc.string()?;
                    Expect::AfterValue
                }
                b't' => {
                    sc.literal(b"true")?;
                    Expect::AfterValue
                }
                b'f' => {
                    sc.literal(b"false")?;
                    Expect::AfterValue
                }
                b'n' => {
                    sc.literal(b"null")?;
                    Expect::AfterValue
                }
                _ => {
                    sc.number()?;
                    Expect::AfterValue
                }
            },
            Expect::AfterValue => match sc.bump() {
                None if stack.depth == 0 => return Ok(()),
                Some(b',') if stack.depth > 0 => {
                    if stack.in_object() {
                        sc.skip_ws();
                        sc.key()?;
                    }
                    Expect::Value
                }
                Some(b'}') => {
                    stack.pop(true)?;
                    Expect::AfterValue
                }
                Some(b']') => {
                    stack.pop(false)?;
                    Expect::AfterValue
                }
                _ => return Err(ArgError::BadJson),
            },
        };
    }
}
