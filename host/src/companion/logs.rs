//! `showmsg` and `savemsg`: the daemon's recent log lines, shown or saved
//! as a file under `logs/`.

use lluav_core::{Args, Command, Fields};

use super::error::{Error, Result};
use super::fit::write_strings;
use crate::files::{Area, Files, atomic_write};
use crate::recent_log::RecentLog;

/// `showmsg` without a count shows this many lines.
const DEFAULT_SHOWMSG: usize = 50;

/// The daemon's recent log.
#[derive(Debug)]
pub(super) struct Logs {
    log: RecentLog,
}

impl Logs {
    pub(super) fn new(log: RecentLog) -> Self {
        Logs { log }
    }

    /// `showmsg [count]` (the last `count` lines, newest first, as many
    /// as fit) and `savemsg`.
    pub(super) fn run(&self, cmd: &Command<'_>, files: &Files, now_ms: i64, out: &mut Fields<'_>) -> Result {
        match cmd.args() {
            &Args::OptCount(n) => {
                let n = n.map_or(DEFAULT_SHOWMSG, |n| usize::try_from(n).unwrap_or(usize::MAX));
                let (mut lines, total) = self.log.recent_of(n);
                lines.reverse();
                write_strings(out, "msgs", lines, total);
                Ok(())
            }
            _ => self.save(files, now_ms, out),
        }
    }

    /// Writes every recent line to a new file `logs/msgs_<now_ms>.log` and
    /// answers its path (relative to the data directory) and line count.
    pub(super) fn save(&self, files: &Files, now_ms: i64, out: &mut Fields<'_>) -> Result {
        let lines = self.log.recent(usize::MAX);
        let name = format!("msgs_{now_ms}.log");
        let path = files.named(Area::Logs, &name)?;
        let mut text = lines.join("\n");
        text.push('\n');
        atomic_write(&path, text.as_bytes(), 0o644).map_err(|e| Error::io(format!("write {name}"), e))?;
        out.str("file", &format!("{}/{name}", Area::Logs.dir_name()))
            .u64("count", lines.len() as u64);
        Ok(())
    }
}
