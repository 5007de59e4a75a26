//! Small state that must survive a restart (lock mode, the map in use,
//! map localisation): a JSON file in the data directory, replaced
//! atomically on every change (temp file, fsync, rename), so a crash
//! leaves the old state or the new one, never a mix.

use std::io;
use std::path::PathBuf;

use serde::Serialize;
use serde::de::DeserializeOwned;

use super::atomic_write;

/// A value kept in `file`, written before the change takes effect.
#[derive(Debug)]
pub(crate) struct Saved<T> {
    file: PathBuf,
    value: T,
}

impl<T: Serialize + DeserializeOwned + Default + Clone> Saved<T> {
    /// Reads `file`; a missing file is the default. A file that cannot be
    /// read stops the daemon: starting unlocked because the lock could not
    /// be read would fail open.
    pub(crate) fn load(file: PathBuf) -> io::Result<Self> {
        let value = match std::fs::read(&file) {
            Ok(bytes) => serde_json::from_slice(&bytes).map_err(|e| {
                io::Error::new(
                    io::ErrorKind::InvalidData,
                    format!("{}: not a state file lluavd wrote ({e})", file.display()),
                )
            })?,
            Err(e) if e.kind() == io::ErrorKind::NotFound => T::default(),
            Err(e) => return Err(e),
        };
        Ok(Saved { file, value })
    }

    /// The value in force.
    pub(crate) fn get(&self) -> &T {
        &self.value
    }

    /// Applies `change` and saves the result; on failure nothing changes.
    pub(crate) fn update(&mut self, change: impl FnOnce(&mut T)) -> io::Result<()> {
        let mut next = self.value.clone();
        change(&mut next);
        let bytes = serde_json::to_vec_pretty(&next).map_err(io::Error::other)?;
        atomic_write(&self.file, &bytes, 0o600)?;
        self.value = next;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Clone, Debug, Default, PartialEq, serde::Deserialize, Serialize)]
    #[serde(default)]
    struct State {
        on: bool,
        name: Option<String>,
    }

    #[test]
    fn a_saved_value_is_read_back_and_a_missing_file_is_the_default() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("state.json");
        let mut s = Saved::<State>::load(file.clone()).unwrap();
        assert_eq!(s.get(), &State::default());
        s.update(|v| (v.on, v.name) = (true, Some("m1".into()))).unwrap();
        let again = Saved::<State>::load(file).unwrap();
        assert_eq!(
            again.get(),
            &State {
                on: true,
                name: Some("m1".into())
            }
        );
    }

    #[test]
    fn a_failed_save_changes_nothing_and_an_unreadable_file_stops_the_load() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("gone").join("state.json");
        let mut s = Saved::<State>::load(file).unwrap();
        assert!(s.update(|v| v.on = true).is_err());
        assert!(!s.get().on);
        let bad = dir.path().join("bad.json");
        std::fs::write(&bad, "{").unwrap();
        let e = Saved::<State>::load(bad).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidData);
    }
}
