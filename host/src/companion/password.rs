//! The password file `passwd` writes (`password` in the data directory,
//! mode 0600), read at start; and the rule that a password pinned by the
//! daemon's configuration is not changed by `passwd`.

use std::io;
use std::path::{Path, PathBuf};

use super::error::{Error, Result};
use crate::files::atomic_write;

/// File in the data directory holding the password `passwd` set.
const PASSWORD_FILE: &str = "password";

/// The saved password and whether the configuration pins it.
#[derive(Debug)]
pub(super) struct Password {
    file: PathBuf,
    stored: Option<String>,
    pinned: bool,
}

impl Password {
    /// Reads the saved password, if there is one.
    pub(super) fn load(root: &Path, pinned: bool) -> io::Result<Self> {
        let file = root.join(PASSWORD_FILE);
        let stored = match std::fs::read_to_string(&file) {
            Ok(p) if !p.is_empty() => Some(p),
            Ok(_) => None,
            Err(e) if e.kind() == io::ErrorKind::NotFound => None,
            Err(e) => return Err(e),
        };
        Ok(Password { file, stored, pinned })
    }

    pub(super) fn stored(&self) -> Option<String> {
        self.stored.clone()
    }

    /// Saves `new` atomically (the old one stays if that fails), unless the
    /// configuration pins the password.
    pub(super) fn set(&mut self, new: &str) -> Result {
        if self.pinned {
            return Err(Error::PasswordPinned);
        }
        atomic_write(&self.file, new.as_bytes(), 0o600).map_err(|e| Error::io("save password", e))?;
        self.stored = Some(new.to_owned());
        tracing::info!("password changed");
        Ok(())
    }
}
