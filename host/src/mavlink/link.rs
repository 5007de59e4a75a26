//! The link to the autopilot and the tasks that keep it alive.
//!
//! One [`Link`] per daemon: the transport (`transport`: lluavd's own UDP,
//! or the crate's serial and TCP connections), a broadcast feed of the
//! followed autopilot's messages (the protocols of [`super::protocol`]
//! wait on it; nothing else reaches it), and what lluavd knows of the
//! autopilot ([`Known`], changed only through its methods, under
//! [`Link::with`]). lluavd sends only to the followed autopilot's
//! address. Tasks run until [`Link::stop`]: the reader, our own
//! `HEARTBEAT` at 1 Hz as an onboard computer, the setpoint stream, each
//! time the link comes up the message rate requests, and the commands
//! waiting for the autopilot ([`Link::spawn`]). Time is the daemon's
//! clock, the one requests are stamped with.

use std::collections::HashMap;
use std::future::Future;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use ::mavlink::MavHeader;
use ::mavlink::dialects::ardupilotmega::{
    HEARTBEAT_DATA, MavAutopilot, MavCmd, MavFrame, MavMessage, MavModeFlag, MavState, MavType,
    PositionTargetTypemask, SET_POSITION_TARGET_LOCAL_NED_DATA,
};
use lluav_core::Clock;
use tokio::runtime::Handle;
use tokio::sync::broadcast;
use tokio::task::{AbortHandle, JoinHandle};
use tokio::time::{Instant, MissedTickBehavior};

use super::effect::Effect;
use super::error::MavError;
use super::follow::Wanted;
use super::protocol::{self, Incoming, Port, Target, Timing};
use super::signing::SigningKey;
use super::state::{Known, Receipt};
use super::transport::{Packet, Transport};

/// `MAV_COMP_ID_ONBOARD_COMPUTER`: lluavd's component id.
pub const OWN_COMPONENT: u8 = 191;
/// How often the active setpoint is re-sent: well above the 2 Hz PX4
/// needs to stay in offboard.
pub const SETPOINT_PERIOD: Duration = Duration::from_millis(100);
/// Messages buffered for slow protocol waiters.
const FEED_CAPACITY: usize = 1024;
/// How often dropped foreign packets are reported in the log, heartbeats.
const FOREIGN_REPORT_EVERY: u32 = 10;
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

/// The daemon's clock.
pub type SharedClock = Arc<dyn Clock + Send + Sync>;

/// How the link is opened.
#[derive(Clone, Debug)]
pub struct LinkConfig {
    /// The `mavlink` crate's address.
    pub address: String,
    /// The protocols' timeouts and retries.
    pub timing: Timing,
    /// lluavd's system id; `None` takes the autopilot's.
    pub own_system: Option<u8>,
    /// The autopilot followed.
    pub wanted: Wanted,
    /// MAVLink 2 signing.
    pub signing: Option<SigningKey>,
    /// lluavd's `max_alt`, m: the log says when the autopilot's own
    /// return climbs higher (lluavd cannot clip it).
    pub max_alt: f64,
}

/// The link to the autopilot.
pub struct Link {
    address: String,
    transport: Transport,
    feed: broadcast::Sender<Arc<Incoming>>,
    known: Mutex<Known>,
    locks: Mutex<HashMap<u32, Arc<tokio::sync::Mutex<()>>>>,
    timing: Timing,
    own_system: Option<u8>,
    max_alt: f64,
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

impl Link {
    /// Opens the transport and starts the link's tasks on the current
    /// tokio runtime; `clock` is the daemon's. Fails if the transport
    /// cannot be opened (a bad address, a port in use, no such serial
    /// device); a serial or TCP link that fails later is reconnected.
    pub async fn open(cfg: LinkConfig, clock: SharedClock) -> std::io::Result<Arc<Link>> {
        let transport = Transport::open(&cfg.address, cfg.signing.as_ref()).await?;
        let link = Arc::new(Link {
            address: cfg.address,
            transport,
            feed: broadcast::channel(FEED_CAPACITY).0,
            known: Mutex::new(Known::new(cfg.wanted)),
            locks: Mutex::new(HashMap::new()),
            timing: cfg.timing,
            own_system: cfg.own_system,
            max_alt: cfg.max_alt,
            clock,
            runtime: Handle::current(),
            tasks: Mutex::new(Vec::new()),
            started: Instant::now(),
        });
        link.spawn(read_loop(Arc::clone(&link)));
        link.spawn(heartbeat_loop(Arc::clone(&link)));
        link.spawn(setpoint_loop(Arc::clone(&link)));
        tracing::info!(address = %link.address, signed = cfg.signing.is_some(), "MAVLink link open");
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
        tracing::info!(address = %self.address, "MAVLink link stopped");
    }

    fn header(&self) -> MavHeader {
        let system = self
            .own_system
            .or_else(|| self.with(|k| k.target()).map(|t| t.system))
            .unwrap_or(1);
        MavHeader {
            system_id: system.into(),
            component_id: OWN_COMPONENT,
            sequence: 0,
        }
    }

    /// Runs `cmd` with the command protocol; a lost acknowledgement is
    /// resolved by `effect` in the telemetry. Commands with the same id
    /// wait for each other (an ACK names only the command).
    pub async fn command(
        &self,
        cmd: MavCmd,
        params: [f32; 7],
        effect: Option<Effect>,
    ) -> Result<(), MavError> {
        let lock = Arc::clone(unpoison(&self.locks).entry(cmd as u32).or_default());
        let _turn = lock.lock().await;
        let timing = self.timing;
        protocol::command(self, &timing, cmd, params, effect).await
    }

    /// Takes in one received packet: the followed autopilot's reach the
    /// cache and the feed, nobody else's.
    fn receive(self: &Arc<Self>, packet: Packet) {
        let now = self.now_ms();
        let Packet { from, header, msg } = packet;
        match self.with(|k| k.receive(from, &header, &msg, now)) {
            Receipt::Dropped => return,
            Receipt::Kept => {}
            Receipt::LinkUp => {
                tracing::info!("MAVLink link up");
                self.spawn(request_rates(Arc::clone(self)));
            }
        }
        // No receiver is fine: nobody waits for the autopilot right now.
        let _ = self.feed.send(Arc::new(Incoming { header, msg }));
    }
}

impl Port for Link {
    async fn send(&self, msg: MavMessage) -> Result<(), MavError> {
        let to = self.with(|k| k.peer());
        self.transport.send(to, self.header(), &msg).await
    }

    fn subscribe(&self) -> broadcast::Receiver<Arc<Incoming>> {
        self.feed.subscribe()
    }

    fn target(&self) -> Result<Target, MavError> {
        self.with(|k| k.target())
            .ok_or_else(|| MavError::LinkLost("no autopilot heartbeat yet".into()))
    }
}

/// Reads everything.
async fn read_loop(link: Arc<Link>) {
    loop {
        match link.transport.recv().await {
            Ok(packets) => packets.into_iter().for_each(|p| link.receive(p)),
            Err(e) => {
                tracing::warn!(error = %e, address = %link.address, "MAVLink receive failed");
                tokio::time::sleep(Duration::from_secs(1)).await;
            }
        }
    }
}

/// Our `HEARTBEAT`, once a second, as an onboard computer.
async fn heartbeat_loop(link: Arc<Link>) {
    let mut every = tokio::time::interval(Duration::from_secs(1));
    every.set_missed_tick_behavior(MissedTickBehavior::Delay);
    for beat in 1u32.. {
        every.tick().await;
        if beat % FOREIGN_REPORT_EVERY == 0 {
            let foreign = link.with(Known::take_foreign);
            if foreign > 0 {
                tracing::info!(foreign, "packets not from the followed autopilot dropped");
            }
        }
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
        let (pose, target) = link.with(|k| (k.setpoint(), k.target()));
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
        if let Err(e) = link
            .command(MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL, params, None)
            .await
        {
            refused.push(format!("{id}: {e}"));
        }
    }
    let version = [AUTOPILOT_VERSION_ID, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    if let Err(e) = link.command(MavCmd::MAV_CMD_REQUEST_MESSAGE, version, None).await {
        refused.push(format!("AUTOPILOT_VERSION: {e}"));
    }
    if refused.is_empty() {
        tracing::info!("telemetry rates set");
    } else {
        tracing::info!(refused = %refused.join("; "), "some telemetry rates were not set");
    }
    read_rtl_alt(&link).await;
}

/// Reads the altitude the autopilot's return climbs to (`rtl` answers
/// it; later `PARAM_VALUE`s of it keep it current) and says in the log
/// when it is above lluavd's `max_alt`: the autopilot's RTL, whoever
/// starts it, climbs there, and lluavd cannot clip it.
async fn read_rtl_alt(link: &Arc<Link>) {
    let Some(flavour) = link.with(|k| k.tel().flavour()) else {
        return;
    };
    let (name, _) = flavour.rtl_alt_param();
    if let Err(e) = protocol::read_param(&**link, link.timing(), name).await {
        tracing::info!(param = name, error = %e, "the autopilot's RTL altitude is unknown");
        return;
    }
    match link.with(|k| k.tel().rtl_alt()) {
        Some(alt) if f64::from(alt) > link.max_alt => tracing::warn!(
            param = name,
            rtl_alt = alt,
            max_alt = link.max_alt,
            "the autopilot's RTL climbs above max_alt: lluavd cannot clip it; set {name} lower on the autopilot"
        ),
        Some(alt) => tracing::info!(param = name, rtl_alt = alt, "the autopilot's RTL altitude"),
        None => {}
    }
}
