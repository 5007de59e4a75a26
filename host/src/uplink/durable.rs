//! Exactly once across a restart (DESIGN.md, "Uplink"): the answers of
//! requests that change the vehicle, kept in the data directory for the
//! 10 minutes their ids are remembered.
//!
//! Each such request is written twice, each time synced to disk before
//! going on: when it starts ([`Entry::Started`], before the command runs)
//! and when it is answered ([`Entry::Answered`], before the answer is
//! published). A restart reads them back ([`Store::open`]): an answered
//! request answers its repeat as before, and one that was running when
//! lluavd stopped answers it -3 instead of running again (the vehicle may
//! or may not have done it).
//!
//! The files are JSON lines in `DATA_DIR/uplink/`, one file per minute
//! of writing (`answers-<unix ms>.jsonl`): every record is forgotten 10
//! minutes after its request, so whole files go once all they hold is
//! older than that, and nothing is ever rewritten. A torn last line (a
//! power cut while writing) is skipped; every run writes a file of its
//! own. One thread writes: records that arrive while it syncs are written
//! and synced together.

use std::collections::HashMap;
use std::fs::{self, File, OpenOptions};
use std::io::{self, BufRead, BufReader, Write};
use std::os::unix::fs::{DirBuilderExt, OpenOptionsExt};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, Receiver, SyncSender, TrySendError};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use tokio::sync::oneshot;

/// The directory under the data directory.
pub const DIR: &str = "uplink";

/// How long one file is written to before the next one starts.
const SEGMENT_MS: i64 = 60_000;

/// Answers longer than this are recorded as answered, not kept: a repeat
/// after a restart is then refused, never run (the file stays small).
pub const MAX_KEPT: usize = 16 << 10;

/// Bytes of answers the files hold for the last window, at most; beyond
/// it answers are recorded as answered, not kept.
pub const MAX_BYTES: u64 = 64 << 20;

/// Records the writer takes at once.
const BATCH: usize = 256;

/// One record.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Entry {
    /// Request `id` of `client`, made at `at` (Unix ms), starts running
    /// command `cmd`.
    Started {
        /// The client id.
        client: String,
        /// The request id.
        id: String,
        /// When the request came, in Unix milliseconds.
        at: i64,
        /// The command's id (for the answer to a repeat after a restart).
        cmd: u8,
    },
    /// The request was answered with `answer` (the envelope as published;
    /// `None`: answered, the answer not kept).
    Answered {
        /// The client id.
        client: String,
        /// The request id.
        id: String,
        /// When the request came, in Unix milliseconds.
        at: i64,
        /// The answer.
        answer: Option<String>,
    },
}

/// A request of the last window found at start.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Found {
    /// The client id.
    pub client: String,
    /// The request id.
    pub id: String,
    /// When the request came, in Unix milliseconds.
    pub at: i64,
    /// What became of it.
    pub outcome: Outcome,
}

/// What a previous run did with a request.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// It answered this.
    Answered(String),
    /// It answered; the answer was not kept.
    AnsweredNotKept,
    /// It was running command `cmd` when lluavd stopped.
    Interrupted(u8),
}

/// A line of a file.
#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct Line {
    t: i64,
    c: String,
    i: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    start: Option<u8>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    answer: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    answered: Option<bool>,
}

impl Line {
    fn of(entry: Entry) -> Line {
        match entry {
            Entry::Started { client, id, at, cmd } => Line {
                t: at,
                c: client,
                i: id,
                start: Some(cmd),
                answer: None,
                answered: None,
            },
            Entry::Answered {
                client,
                id,
                at,
                answer,
            } => Line {
                t: at,
                c: client,
                i: id,
                start: None,
                answered: answer.is_none().then_some(true),
                answer,
            },
        }
    }
}

/// The line `entry` is written as (without its line break).
pub fn line(entry: Entry) -> String {
    // Strings and numbers only: serialising cannot fail.
    serde_json::to_string(&Line::of(entry)).unwrap_or_default()
}

/// The requests of the last `window_ms` before `now` (Unix ms) that
/// `lines` record, each with what last became of it; lines that cannot be
/// read (a torn write) are skipped.
pub fn replay(lines: impl IntoIterator<Item = impl AsRef<[u8]>>, now: i64, window_ms: i64) -> Vec<Found> {
    let mut replay = Replay::new(now, window_ms);
    for line in lines {
        replay.line(line.as_ref());
    }
    replay.finish()
}

/// A replay in progress, one line at a time.
#[derive(Debug)]
pub struct Replay {
    now: i64,
    window_ms: i64,
    found: HashMap<(String, String), Found>,
    order: Vec<(String, String)>,
}

impl Replay {
    /// A replay at `now` (Unix ms) of the last `window_ms`.
    pub fn new(now: i64, window_ms: i64) -> Replay {
        Replay {
            now,
            window_ms,
            found: HashMap::new(),
            order: Vec::new(),
        }
    }

    /// Takes one line of a file.
    pub fn line(&mut self, line: &[u8]) {
        let Ok(line) = serde_json::from_slice::<Line>(line) else {
            return;
        };
        let outcome = match (line.start, line.answer, line.answered) {
            (Some(cmd), None, None) => Outcome::Interrupted(cmd),
            (None, Some(answer), None) => Outcome::Answered(answer),
            (None, None, Some(true)) => Outcome::AnsweredNotKept,
            _ => return,
        };
        // A record from the future (the clock went back) still counts.
        if self.now.saturating_sub(line.t) >= self.window_ms {
            return;
        }
        let key = (line.c, line.i);
        match self.found.get_mut(&key) {
            // A repeat after the window runs again: its new start is newer.
            Some(f) if f.at <= line.t => {
                f.at = line.t;
                f.outcome = outcome;
            }
            Some(_) => {}
            None => {
                self.order.push(key.clone());
                let found = Found {
                    client: key.0.clone(),
                    id: key.1.clone(),
                    at: line.t,
                    outcome,
                };
                self.found.insert(key, found);
            }
        }
    }

    /// What the lines say, in the order the requests first appeared.
    pub fn finish(mut self) -> Vec<Found> {
        self.order
            .into_iter()
            .filter_map(|k| self.found.remove(&k))
            .collect()
    }
}

/// A write the thread is asked for, and where to say it is on disk.
type Job = (Entry, oneshot::Sender<io::Result<()>>);

/// The durable store: a thread that writes and syncs.
#[derive(Debug)]
pub struct Store {
    jobs: SyncSender<Job>,
}

impl Store {
    /// Opens the store in `data_dir` at `now` (Unix ms): reads what the
    /// files of the last `window` hold, deletes the files that hold
    /// nothing younger, and starts the writer on a file of its own.
    pub fn open(data_dir: &Path, window: Duration, now: i64) -> io::Result<(Store, Vec<Found>)> {
        let dir = data_dir.join(DIR);
        fs::DirBuilder::new().recursive(true).mode(0o700).create(&dir)?;
        let window_ms = i64::try_from(window.as_millis()).unwrap_or(i64::MAX);
        let mut segments = segments(&dir)?;
        let mut replay = Replay::new(now, window_ms);
        for (_, path) in &segments {
            for line in BufReader::new(File::open(path)?).split(b'\n') {
                replay.line(&line?);
            }
        }
        let found = replay.finish();
        let mut bytes = segments
            .iter()
            .filter_map(|(_, p)| fs::metadata(p).ok())
            .map(|m| m.len())
            .sum();
        let current = Segment::create(&dir, now)?;
        segments.push((now, current.path.clone()));
        bytes = prune(&mut segments, now, window_ms, bytes);
        let (jobs, rx) = mpsc::sync_channel(BATCH);
        let writer = Writer {
            dir,
            segments,
            current,
            window_ms,
            bytes,
        };
        std::thread::Builder::new()
            .name("lluavd-uplink-store".into())
            .spawn(move || writer.run(&rx))?;
        Ok((Store { jobs }, found))
    }

    /// Writes `entry` and returns once it is on disk.
    pub async fn write(&self, entry: Entry) -> io::Result<()> {
        let (tx, rx) = oneshot::channel();
        let mut job = (entry, tx);
        // The thread takes a batch at a time: a full queue empties within
        // one sync. Waiting here keeps the runtime's threads free.
        loop {
            match self.jobs.try_send(job) {
                Ok(()) => break,
                Err(TrySendError::Full(back)) => {
                    job = back;
                    tokio::time::sleep(Duration::from_millis(1)).await;
                }
                Err(TrySendError::Disconnected(_)) => {
                    return Err(io::Error::other("the uplink's store has stopped"));
                }
            }
        }
        rx.await
            .unwrap_or_else(|_| Err(io::Error::other("the uplink's store has stopped")))
    }
}

/// The files in `dir` with the time they were started, oldest first.
fn segments(dir: &Path) -> io::Result<Vec<(i64, PathBuf)>> {
    let mut found = Vec::new();
    for entry in fs::read_dir(dir)? {
        let path = entry?.path();
        let start = path
            .file_name()
            .and_then(|n| n.to_str())
            .and_then(|n| n.strip_prefix("answers-"))
            .and_then(|n| n.strip_suffix(".jsonl"))
            .and_then(|n| n.parse::<i64>().ok());
        if let Some(start) = start {
            found.push((start, path));
        }
    }
    found.sort();
    Ok(found)
}

/// Deletes the files whose every record is older than the window (a file
/// started at `start` holds records written before `start + SEGMENT_MS`,
/// of requests made before that); the bytes left.
fn prune(segments: &mut Vec<(i64, PathBuf)>, now: i64, window_ms: i64, mut bytes: u64) -> u64 {
    segments.retain(|(start, path)| {
        if now.saturating_sub(start.saturating_add(SEGMENT_MS)) < window_ms {
            return true;
        }
        bytes = bytes.saturating_sub(fs::metadata(path).map_or(0, |m| m.len()));
        // A file that cannot be deleted is read again at the next start,
        // where its records are too old to count.
        let _ = fs::remove_file(path);
        false
    });
    bytes
}

/// The file being written.
struct Segment {
    file: File,
    path: PathBuf,
    start: i64,
}

impl Segment {
    fn create(dir: &Path, now: i64) -> io::Result<Segment> {
        // A name of its own even when two files start in one millisecond.
        let mut start = now;
        loop {
            let path = dir.join(format!("answers-{start}.jsonl"));
            match OpenOptions::new()
                .append(true)
                .create_new(true)
                .mode(0o600)
                .open(&path)
            {
                Ok(file) => {
                    // The new name itself must survive a power cut.
                    File::open(dir)?.sync_all()?;
                    return Ok(Segment { file, path, start });
                }
                Err(e) if e.kind() == io::ErrorKind::AlreadyExists => start += 1,
                Err(e) => return Err(e),
            }
        }
    }
}

/// The writer thread's state.
struct Writer {
    dir: PathBuf,
    segments: Vec<(i64, PathBuf)>,
    current: Segment,
    window_ms: i64,
    /// Bytes the files hold.
    bytes: u64,
}

impl Writer {
    fn run(mut self, jobs: &Receiver<Job>) {
        while let Ok(first) = jobs.recv() {
            let mut batch = vec![first];
            while batch.len() < BATCH
                && let Ok(more) = jobs.try_recv()
            {
                batch.push(more);
            }
            let (entries, replies): (Vec<Entry>, Vec<_>) = batch.into_iter().unzip();
            let written = self.write(entries);
            for reply in replies {
                let result = match &written {
                    Ok(()) => Ok(()),
                    Err(e) => Err(io::Error::new(e.kind(), e.to_string())),
                };
                let _ = reply.send(result);
            }
        }
    }

    fn write(&mut self, entries: Vec<Entry>) -> io::Result<()> {
        let now = super::serve::unix_ms();
        if now.saturating_sub(self.current.start) >= SEGMENT_MS {
            self.current = Segment::create(&self.dir, now)?;
            self.segments
                .push((self.current.start, self.current.path.clone()));
            self.bytes = prune(&mut self.segments, now, self.window_ms, self.bytes);
        }
        let mut text = Vec::new();
        for entry in entries {
            let mut line = Line::of(entry);
            let too_much = self.bytes + text.len() as u64 > MAX_BYTES;
            if line
                .answer
                .as_ref()
                .is_some_and(|a| a.len() > MAX_KEPT || too_much)
            {
                line.answer = None;
                line.answered = Some(true);
            }
            serde_json::to_writer(&mut text, &line).map_err(io::Error::other)?;
            text.push(b'\n');
        }
        self.current.file.write_all(&text)?;
        self.current.file.sync_data()?;
        self.bytes += text.len() as u64;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn started(id: &str, at: i64) -> Entry {
        Entry::Started {
            client: "op".into(),
            id: id.into(),
            at,
            cmd: 18,
        }
    }

    fn answered(id: &str, at: i64, answer: Option<&str>) -> Entry {
        Entry::Answered {
            client: "op".into(),
            id: id.into(),
            at,
            answer: answer.map(str::to_owned),
        }
    }

    #[test]
    fn a_replay_gives_the_last_word_on_each_request_of_the_window() {
        let lines = [
            line(started("a", 1000)),
            line(started("b", 1000)),
            line(answered("a", 1000, Some(r#"{"id":"a"}"#))),
            line(started("c", 1000)),
            line(answered("c", 1000, None)),
            line(started("old", 100)),
            "{\"t\":1000,\"c\":\"op\",\"i\":\"torn".to_owned(),
            "garbage".to_owned(),
        ];
        let found = replay(&lines, 1500, 1000);
        let outcomes: Vec<(&str, &Outcome)> = found.iter().map(|f| (f.id.as_str(), &f.outcome)).collect();
        assert_eq!(
            outcomes,
            [
                ("a", &Outcome::Answered(r#"{"id":"a"}"#.into())),
                ("b", &Outcome::Interrupted(18)),
                ("c", &Outcome::AnsweredNotKept),
            ]
        );
    }

    #[tokio::test]
    async fn what_is_written_is_found_by_the_next_run_and_old_files_go() {
        let dir = tempfile::tempdir().expect("temp dir");
        let window = Duration::from_secs(600);
        let now = super::super::serve::unix_ms();
        let (store, found) = Store::open(dir.path(), window, now).expect("opened");
        assert!(found.is_empty());
        store.write(started("t1", now)).await.expect("written");
        store
            .write(answered("t1", now, Some(r#"{"id":"t1","response":{"ret":0}}"#)))
            .await
            .expect("written");
        store.write(started("t2", now)).await.expect("written");
        let big = "x".repeat(MAX_KEPT + 1);
        store
            .write(answered("t3", now, Some(&big)))
            .await
            .expect("written");
        drop(store);
        // A file far older than the window, and the next run.
        let old = dir.path().join(DIR).join("answers-1000.jsonl");
        std::fs::write(&old, line(started("ancient", 1000)) + "\n").expect("old file");
        let (_store, found) = Store::open(dir.path(), window, now + 1).expect("opened again");
        let by_id: HashMap<&str, &Outcome> = found.iter().map(|f| (f.id.as_str(), &f.outcome)).collect();
        assert_eq!(
            by_id.get("t1"),
            Some(&&Outcome::Answered(r#"{"id":"t1","response":{"ret":0}}"#.into()))
        );
        assert_eq!(by_id.get("t2"), Some(&&Outcome::Interrupted(18)));
        assert_eq!(
            by_id.get("t3"),
            Some(&&Outcome::AnsweredNotKept),
            "too long to keep"
        );
        assert!(!by_id.contains_key("ancient"));
        assert!(!old.exists(), "a file older than the window is deleted");
        let files = segments(&dir.path().join(DIR)).expect("listed");
        assert_eq!(files.len(), 2, "each run writes a file of its own: {files:?}");
    }
}
