//! MAVLink 2 message signing (`--mavlink-signing-key FILE`): the shared
//! secret, read from a file of 64 hex digits. With a key, lluavd signs
//! everything it sends and drops every message that is unsigned,
//! MAVLink 1, or signed with another key or replayed (the `mavlink`
//! crate's checks).

use std::path::Path;
use std::sync::Arc;

use ::mavlink::{SigningConfig, SigningData};

/// The link id lluavd signs with (one link per daemon).
const LINK_ID: u8 = 0;

/// A MAVLink 2 signing key: 32 bytes.
#[derive(Clone, PartialEq, Eq)]
pub struct SigningKey([u8; 32]);

impl std::fmt::Debug for SigningKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // A secret stays out of logs.
        f.write_str("SigningKey(..)")
    }
}

impl SigningKey {
    /// A key from 64 hex digits (surrounding whitespace ignored).
    pub fn from_hex(text: &str) -> Result<SigningKey, String> {
        let text = text.trim();
        let digits: Vec<u8> = text
            .chars()
            .map(|c| c.to_digit(16).and_then(|d| u8::try_from(d).ok()))
            .collect::<Option<_>>()
            .ok_or("a MAVLink signing key is hex digits only")?;
        if digits.len() != 64 {
            return Err(format!(
                "a MAVLink signing key is 32 bytes, 64 hex digits; this one has {} digits",
                digits.len()
            ));
        }
        let mut key = [0u8; 32];
        for (byte, pair) in key.iter_mut().zip(digits.chunks_exact(2)) {
            if let [high, low] = pair {
                *byte = (high << 4) | low;
            }
        }
        Ok(SigningKey(key))
    }

    /// The key in `path`.
    pub fn read(path: &Path) -> Result<SigningKey, String> {
        let text =
            std::fs::read_to_string(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        SigningKey::from_hex(&text).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// What the `mavlink` crate signs and checks with: sign everything
    /// sent, accept only messages signed with this key.
    pub fn data(&self) -> Arc<SigningData> {
        Arc::new(SigningData::from_config(SigningConfig::new(
            self.0, LINK_ID, true, false,
        )))
    }

    /// The crate's configuration, for a connection it runs itself.
    pub fn config(&self) -> SigningConfig {
        SigningConfig::new(self.0, LINK_ID, true, false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_key_is_64_hex_digits() {
        let hex = "0102030405060708090a0b0c0d0e0f101112131415161718191a1b1c1d1e1f20";
        let key = SigningKey::from_hex(&format!("{hex}\n")).unwrap();
        assert_eq!(key.0[0], 1);
        assert_eq!(key.0[31], 0x20);
        assert_eq!(SigningKey::from_hex(&hex.to_uppercase()), Ok(key.clone()));
        assert!(SigningKey::from_hex(&hex[2..]).unwrap_err().contains("62 digits"));
        assert!(SigningKey::from_hex(&format!("{}zz", &hex[2..])).is_err());
        assert!(SigningKey::from_hex("").is_err());
        assert_eq!(format!("{key:?}"), "SigningKey(..)");
    }
}
