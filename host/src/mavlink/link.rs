//! The link to the autopilot and the tasks that keep it alive.
//!
//! One [`Link`] per daemon: the connection (reconnected when a TCP or
//! serial link fails), a broadcast feed of every message received (the
//! protocols of [`super::protocol`] wait on it), and what lluavd knows of
//! the autopilot ([`Known`], changed only through its methods, under
//! [`Link::with`]). Tasks run until [`Link::stop`]: the reader (cache,
//! counts, mission progress, the feed), our own `HEARTBEAT` at 1 Hz as an
//! onboard computer, the setpoint stream, each time the link comes up the
//! message rate requests, and the commands waiting for the autopilot
//! ([`Link::spawn`]). Time is the daemon's clock, the one requests are
//! stamped with.

use std::collections::HashMap;
use std::future::Future;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use ::mavlink::dialects::ardupilotmega::{
    HEARTBEAT_DATA, MavAutopilot, MavCmd, MavFrame, MavMessage, MavModeFlag, MavState, MavType,
    PositionTargetTypemask, SET_POSITION_TARGET_LOCAL_NED_DATA,
};
use ::mavlink::error::MessageReadError;
use ::mavlink::{AsyncConnection, AsyncMavConnection as _, MavHeader};
use lluav_core::Clock;
use tokio::runtime::Handle;
use tokio::sync::broadcast;
use tokio::task::{AbortHandle, JoinHandle};
use tokio::time::{Instant, MissedTickBehavior};

use super::error::MavError;
use super::protocol::{self, Incoming, Port, Target, Timing};
use super::state::Known;

/// `MAV_COMP_ID_ONBOARD_COMPUTER`: lluavd's component id.
pub const OWN_COMPONENT: u8 = 191;
/// How often the active setpoint is re-sent: well above the 2 Hz PX4
/// needs to stay in offboard.
pub const SETPOINT_PERIOD: Duration = Duration::from_millis(100);
/// How long to wait before reconnecting a failed link.
const RECONNECT_DELAY: Duration = Duration::from_secs(1);
/// Messages buffered for slow protocol waiters.
const FEED_CAPACITY: usize = 1024;
/// `SET_POSITION_TARGET_LOCAL_NED`: position and yaw; velocity,
/// acceleration and yaw rate ignored.
const POSITION_AND_YAW: PositionTargetTypemask = PositionTargetTypemask::from_bits_truncate(
    PositionTargetTypemask::POSITION_TARGET_TYPEMASK_VX_IGNORE.bits()
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_VY_IGNORE.bits()
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_VZ_IGNORE.bits()
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AX_IGNORE.bits()
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AY_IGNORE.bits()
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AZ_IGNORE.bits()
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE.bits(),
);
/// The message rates lluavd asks for: (message id, Hz).
const RATES: [(u32, f32); 8] = [
    (1, 2.0),   // SYS_STATUS
    (30, 10.0), // ATTITUDE
    (32, 10.0), // LOCAL_POSITION_NED
    (33, 5.0),  // GLOBAL_POSITION_INT
    (42, 2.0),  // MISSION_CURRENT
    (147, 1.0), // BATTERY_STATUS
    (242, 1.0), // HOME_POSITION
    (245, 2.0), // EXTENDED_SYS_STATE
];
/// `AUTOPILOT_VERSION`, asked for once per link-up.
const AUTOPILOT_VERSION_ID: f32 = 148.0;

type Conn = AsyncConnection<MavMessage>;

/// The daemon's clock.
pub type SharedClock = Arc<dyn Clock + Send + Sync>;

/// The link to the autopilot.
pub struct Link {
    address: String,
    conn: Mutex<Option<Arc<Conn>>>,
    feed: broadcast::Sender<Arc<Incoming>>,
    known: Mutex<Known>,
    locks: Mutex<HashMap<u32, Arc<tokio::sync::Mutex<()>>>>,
    timing: Timing,
    own_system: Option<u8>,
    clock: SharedClock,
    runtime: Handle,
    /// Every task the link runs, for [`Link::stop`].
    tasks: Mutex<Vec<AbortHandle>>,
    started: Instant,
}

fn unpoison<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // Nothing here panics while holding these locks; if something did,
    // the cache is still the best there is.
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

async fn connect(address: &str) -> std::io::Result<Conn> {
    let mut conn = ::mavlink::connect_async::<MavMessage>(address).await?;
    // ArduPilot on a serial port speaks MAVLink 1 until it hears MAVLink 2.
    conn.set_allow_recv_any_version(true);
    Ok(conn)
}

impl Link {
    /// Connects to `address` (the `mavlink` crate's syntax) and starts
    /// the link's tasks on the current tokio runtime; `clock` is the
    /// daemon's. Fails if the first connection cannot be made (a bad
    /// address, a port in use, no such serial device); later failures are
    /// reconnected.
    pub async fn open(
        address: &str,
        timing: Timing,
        own_system: Option<u8>,
        clock: SharedClock,
    ) -> std::io::Result<Arc<Link>> {
        let conn = connect(address).await?;
        let link = Arc::new(Link {
            address: address.to_owned(),
            conn: Mutex::new(Some(Arc::new(conn))),
            feed: broadcast::channel(FEED_CAPACITY).0,
            known: Mutex::new(Known::default()),
            locks: Mutex::new(HashMap::new()),
            timing,
            own_system,
            clock,
            runtime: Handle::current(),
            tasks: Mutex::new(Vec::new()),
            started: Instant::now(),
        });
        link.spawn(read_loop(Arc::clone(&link)));
        link.spawn(heartbeat_loop(Arc::clone(&link)));
        link.spawn(setpoint_loop(Arc::clone(&link)));
        tracing::info!(address, "MAVLink link open");
        Ok(link)
    }

    /// Runs `f` on what lluavd knows of the autopilot, locked.
    pub fn with<R>(&self, f: impl FnOnce(&mut Known) -> R) -> R {
        f(&mut unpoison(&self.known))
    }

    /// Now, on the daemon's clock.
    pub fn now_ms(&self) -> i64 {
        self.clock.unix_ms()
    }

    /// The protocols' timeouts and retries.
    pub fn timing(&self) -> &Timing {
        &self.timing
    }

    /// Runs `task` on the link's runtime until it ends or the link stops.
    pub fn spawn<T: Send + 'static>(&self, task: impl Future<Output = T> + Send + 'static) -> JoinHandle<T> {
        let handle = self.runtime.spawn(task);
        let mut tasks = unpoison(&self.tasks);
        tasks.retain(|t| !t.is_finished());
        tasks.push(handle.abort_handle());
        handle
    }

    /// Stops every task of the link: nothing is sent or read any more, and
    /// the commands still waiting answer -3.
    pub fn stop(&self) {
        for task in unpoison(&self.tasks).drain(..) {
            task.abort();
        }
        *unpoison(&self.conn) = None;
        tracing::info!(address = %self.address, "MAVLink link stopped");
    }

    fn header(&self) -> MavHeader {
        let system = self
            .own_system
            .or_else(|| self.with(|k| k.tel().target()).map(|t| t.system))
            .unwrap_or(1);
        MavHeader {
            system_id: system.into(),
            component_id: OWN_COMPONENT,
            sequence: 0,
        }
    }

    /// Runs `cmd` with the command protocol; commands with the same id
    /// wait for each other (an ACK names only the command).
    pub async fn command(&self, cmd: MavCmd, params: [f32; 7]) -> Result<(), MavError> {
        let lock = Arc::clone(unpoison(&self.locks).entry(cmd as u32).or_default());
        let _turn = lock.lock().await;
        let timing = self.timing;
        protocol::command(self, &timing, cmd, params).await
    }

    /// Takes in one received message.
    fn receive(self: &Arc<Self>, header: MavHeader, msg: MavMessage) {
        let now = self.now_ms();
        let came_up = self.with(|k| k.observe(&header, &msg, now));
        // No receiver is fine: nobody waits for the autopilot right now.
        let _ = self.feed.send(Arc::new(Incoming { header, msg }));
        if came_up {
            tracing::info!("MAVLink link up");
            self.spawn(request_rates(Arc::clone(self)));
        }
    }
}

impl Port for Link {
    async fn send(&self, msg: MavMessage) -> Result<(), MavError> {
        let conn = unpoison(&self.conn).clone();
        let conn = conn.ok_or_else(|| MavError::Send(format!("not connected to {}", self.address)))?;
        conn.send(&self.header(), &msg)
            .await
            .map(|_| ())
            .map_err(|e| MavError::Send(e.to_string()))
    }

    fn subscribe(&self) -> broadcast::Receiver<Arc<Incoming>> {
        self.feed.subscribe()
    }

    fn target(&self) -> Result<Target, MavError> {
        self.with(|k| k.tel().target())
            .ok_or_else(|| MavError::LinkLost("no autopilot heartbeat yet".into()))
    }
}

/// Reads everything, reconnecting when the connection fails.
async fn read_loop(link: Arc<Link>) {
    loop {
        let conn = unpoison(&link.conn).clone();
        let Some(conn) = conn else {
            tokio::time::sleep(RECONNECT_DELAY).await;
            match connect(&link.address).await {
                Ok(c) => {
                    tracing::info!(address = %link.address, "MAVLink reconnected");
                    *unpoison(&link.conn) = Some(Arc::new(c));
                }
                Err(e) => tracing::debug!(error = %e, "MAVLink reconnect failed"),
            }
            continue;
        };
        match conn.recv().await {
            Ok((header, msg)) => link.receive(header, msg),
            Err(MessageReadError::Parse(e)) => tracing::debug!(error = %e, "MAVLink frame dropped"),
            Err(MessageReadError::Io(e)) => {
                tracing::warn!(error = %e, address = %link.address, "MAVLink connection failed; reconnecting");
                *unpoison(&link.conn) = None;
            }
        }
    }
}

/// Our `HEARTBEAT`, once a second, as an onboard computer.
async fn heartbeat_loop(link: Arc<Link>) {
    let mut every = tokio::time::interval(Duration::from_secs(1));
    every.set_missed_tick_behavior(MissedTickBehavior::Delay);
    loop {
        every.tick().await;
        let hb = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: 0,
            mavtype: MavType::MAV_TYPE_ONBOARD_CONTROLLER,
            autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
            base_mode: MavModeFlag::empty(),
            system_status: MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        });
        if let Err(e) = link.send(hb).await {
            tracing::debug!(error = %e, "heartbeat not sent");
        }
    }
}

/// Re-sends the active setpoint every [`SETPOINT_PERIOD`].
async fn setpoint_loop(link: Arc<Link>) {
    let mut every = tokio::time::interval(SETPOINT_PERIOD);
    every.set_missed_tick_behavior(MissedTickBehavior::Delay);
    loop {
        every.tick().await;
        let (pose, target) = link.with(|k| (k.setpoint(), k.tel().target()));
        let (Some(p), Some(t)) = (pose, target) else {
            continue;
        };
        let msg = MavMessage::SET_POSITION_TARGET_LOCAL_NED(SET_POSITION_TARGET_LOCAL_NED_DATA {
            time_boot_ms: u32::try_from(link.started.elapsed().as_millis()).unwrap_or(u32::MAX),
            x: p.x,
            y: p.y,
            z: p.z,
            vx: 0.0,
            vy: 0.0,
            vz: 0.0,
            afx: 0.0,
            afy: 0.0,
            afz: 0.0,
            yaw: p.yaw,
            yaw_rate: 0.0,
            type_mask: POSITION_AND_YAW,
            target_system: t.system,
            target_component: t.component,
            coordinate_frame: MavFrame::MAV_FRAME_LOCAL_NED,
        });
        if let Err(e) = link.send(msg).await {
            tracing::debug!(error = %e, "setpoint not sent");
        }
    }
}

/// Asks the autopilot for the telemetry rates lluavd needs and for its
/// version; refusals are logged (an autopilot may stream them anyway).
async fn request_rates(link: Arc<Link>) {
    let mut refused = Vec::new();
    for (id, hz) in RATES {
        let params = [id as f32, 1e6 / hz, 0.0, 0.0, 0.0, 0.0, 0.0];
        if let Err(e) = link.command(MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL, params).await {
            refused.push(format!("{id}: {e}"));
        }
    }
    let version = [AUTOPILOT_VERSION_ID, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    if let Err(e) = link.command(MavCmd::MAV_CMD_REQUEST_MESSAGE, version).await {
        refused.push(format!("AUTOPILOT_VERSION: {e}"));
    }
    if refused.is_empty() {
        tracing::info!("telemetry rates set");
    } else {
        tracing::info!(refused = %refused.join("; "), "some telemetry rates were not set");
    }
}
