//! The commands that wait for the autopilot, as async sequences run on
//! their own tasks: what they change on the vehicle's side (the mission
//! on the autopilot, the run, the setpoint stream) they record in the
//! link's shared state themselves, so a client that leaves early loses
//! nothing.

use std::sync::Arc;

#[allow(deprecated)]
use ::mavlink::dialects::ardupilotmega::MISSION_SET_CURRENT_DATA;
use ::mavlink::dialects::ardupilotmega::{MISSION_ITEM_INT_DATA, MavCmd, MavMessage, MavParamType};

use super::autopilot::{self, Flavour, Mode, ParamValue};
use super::error::MavError;
use super::link::{Link, SETPOINT_PERIOD};
use super::mission::{Mission, OnAutopilot, Run, Status};
use super::protocol::{self, Port};

/// `MAV_CMD_COMPONENT_ARM_DISARM` param 2 that forces a disarm.
const FORCE_DISARM: f32 = 21196.0;

/// What a finished command reports.
#[derive(Clone, Debug, PartialEq)]
pub enum Answer {
    /// Acknowledged; the response is written from the telemetry.
    Done,
    /// Took off towards this altitude above home.
    Takeoff {
        /// Metres above home.
        target_alt: f32,
    },
    /// A parameter's value.
    Param {
        /// Its name.
        name: String,
        /// Its value.
        value: ParamValue,
        /// Its type.
        ty: MavParamType,
        /// Its index on the autopilot.
        index: u16,
        /// How many parameters the autopilot has.
        count: u16,
    },
    /// Every parameter, by index.
    Params(Vec<(String, ParamValue)>),
    /// A mission is on the autopilot.
    Mission {
        /// Its external id.
        ext_id: u32,
        /// Its waypoints.
        waypoints: usize,
        /// The mission items uploaded.
        items: usize,
    },
    /// A run started.
    Exec {
        /// The mission.
        ext_id: u32,
        /// The waypoints it flies.
        wp_ids: Vec<u32>,
    },
}

/// A command, acknowledged.
pub async fn command(link: Arc<Link>, cmd: MavCmd, params: [f32; 7]) -> Result<Answer, MavError> {
    link.command(cmd, params).await.map(|()| Answer::Done)
}

/// Switches the flight mode.
pub async fn set_mode(link: &Link, flavour: Flavour, mode: Mode) -> Result<(), MavError> {
    let [p1, p2, p3] = flavour.set_mode_params(mode).ok_or(MavError::Unsupported)?;
    link.command(MavCmd::MAV_CMD_DO_SET_MODE, [p1, p2, p3, 0.0, 0.0, 0.0, 0.0])
        .await
}

/// Arms and takes off to `alt` metres above home. ArduPilot is put in
/// GUIDED first. A refused takeoff disarms again rather than leave an
/// armed vehicle on the ground.
pub async fn takeoff(link: Arc<Link>, flavour: Flavour, alt: f32) -> Result<Answer, MavError> {
    if flavour == Flavour::ArduPilot {
        set_mode(&link, flavour, Mode::Guided).await?;
    }
    link.command(
        MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
        [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    )
    .await?;
    // PX4 takes the takeoff altitude above mean sea level; ArduPilot above
    // home. NaN lets PX4 use its own MIS_TAKEOFF_ALT when home is unknown.
    let param7 = match (flavour, link.shared().tel.home_global()) {
        (Flavour::ArduPilot, _) => alt,
        (_, Some(home)) => (home.alt + f64::from(alt)) as f32,
        (_, None) => f32::NAN,
    };
    let nan = f32::NAN;
    let params = [0.0, 0.0, 0.0, nan, nan, nan, param7];
    if let Err(e) = link.command(MavCmd::MAV_CMD_NAV_TAKEOFF, params).await {
        let disarm = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        if let Err(again) = link.command(MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, disarm).await {
            tracing::warn!(error = %again, "could not disarm after a refused takeoff");
        }
        return Err(e);
    }
    Ok(Answer::Takeoff { target_alt: alt })
}

/// Disarms at once, in the air too (the protocol's `disarm` is a force
/// disarm); the setpoint stream stops.
pub async fn disarm(link: Arc<Link>) -> Result<Answer, MavError> {
    link.shared().stream = None;
    let params = [0.0, FORCE_DISARM, 0.0, 0.0, 0.0, 0.0, 0.0];
    command(link, MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, params).await
}

/// Puts the autopilot in the mode that follows the (already streaming)
/// setpoint. The stream stops if the autopilot refuses.
pub async fn follow_setpoints(link: Arc<Link>, flavour: Flavour) -> Result<Answer, MavError> {
    // PX4 refuses offboard unless setpoints already arrive: let a few go.
    tokio::time::sleep(SETPOINT_PERIOD * 3).await;
    match set_mode(&link, flavour, Mode::Guided).await {
        Ok(()) => Ok(Answer::Done),
        Err(e) => {
            link.shared().stream = None;
            Err(e)
        }
    }
}

/// Uploads `mission` as `items` and records it as the autopilot's.
pub async fn upload(
    link: Arc<Link>,
    mission: Mission,
    items: Vec<MISSION_ITEM_INT_DATA>,
    first_seq: u16,
) -> Result<Answer, MavError> {
    protocol::upload_mission(&*link, &link.timing, &items).await?;
    let answer = Answer::Mission {
        ext_id: mission.ext_id,
        waypoints: mission.waypoints.len(),
        items: items.len(),
    };
    let mut shared = link.shared();
    shared.missions.on_autopilot = Some(OnAutopilot {
        ext_id: mission.ext_id,
        wp_ids: mission.waypoints.iter().map(|w| w.id).collect(),
        first_seq,
    });
    shared.missions.submit(mission);
    Ok(answer)
}

// MISSION_SET_CURRENT is superseded by MAV_CMD_DO_SET_MISSION_CURRENT
// (2022), which older autopilots (and MAVSDK's mission server) lack.
#[allow(deprecated)]
/// Flies `plan`: uploads `items` first when the autopilot holds another
/// mission, then `MISSION_SET_CURRENT` to its first waypoint and
/// `MAV_CMD_MISSION_START`.
pub async fn exec(
    link: Arc<Link>,
    plan: OnAutopilot,
    items: Option<Vec<MISSION_ITEM_INT_DATA>>,
) -> Result<Answer, MavError> {
    if let Some(items) = items {
        protocol::upload_mission(&*link, &link.timing, &items).await?;
        link.shared().missions.on_autopilot = Some(plan.clone());
    }
    let target = link.target()?;
    link.send(MavMessage::MISSION_SET_CURRENT(MISSION_SET_CURRENT_DATA {
        seq: plan.first_seq,
        target_system: target.system,
        target_component: target.component,
    }))
    .await?;
    let answer = Answer::Exec {
        ext_id: plan.ext_id,
        wp_ids: plan.wp_ids.clone(),
    };
    {
        let mut shared = link.shared();
        shared.stream = None;
        shared.missions.run = Some(Run {
            plan,
            reached: Vec::new(),
            current: None,
            status: Status::Running,
        });
    }
    if let Err(e) = link.command(MavCmd::MAV_CMD_MISSION_START, [0.0; 7]).await {
        link.shared().missions.run = None;
        return Err(e);
    }
    Ok(answer)
}

/// Reads a parameter.
pub async fn get_param(link: Arc<Link>, name: String) -> Result<Answer, MavError> {
    let v = protocol::read_param(&*link, &link.timing, &name).await?;
    let value = link.shared().tel.encoding().decode(v.param_type, v.param_value);
    Ok(Answer::Param {
        name,
        value,
        ty: v.param_type,
        index: v.param_index,
        count: v.param_count,
    })
}

/// Reads every parameter.
pub async fn all_params(link: Arc<Link>) -> Result<Answer, MavError> {
    let values = protocol::read_all_params(&*link, &link.timing).await?;
    let encoding = link.shared().tel.encoding();
    Ok(Answer::Params(
        values
            .iter()
            .map(|v| {
                let name = v.param_id.to_str().unwrap_or("").to_owned();
                (name, encoding.decode(v.param_type, v.param_value))
            })
            .collect(),
    ))
}

/// Writes a parameter: reads it first for its type, checks `text`
/// against that type, writes it in the autopilot's encoding and checks
/// the value the autopilot reports back.
pub async fn set_param(link: Arc<Link>, name: String, text: String) -> Result<Answer, MavError> {
    let current = protocol::read_param(&*link, &link.timing, &name).await?;
    let ty = current.param_type;
    let value = autopilot::parse_value(&name, ty, &text).map_err(MavError::Invalid)?;
    let encoding = link.shared().tel.encoding();
    let echo = protocol::write_param(&*link, &link.timing, &name, encoding.encode(ty, value), ty).await?;
    let got = encoding.decode(echo.param_type, echo.param_value);
    if got != value {
        return Err(MavError::State(format!(
            "the autopilot kept {name} at {}",
            show(got)
        )));
    }
    Ok(Answer::Param {
        name,
        value: got,
        ty,
        index: echo.param_index,
        count: echo.param_count,
    })
}

/// A value as text.
fn show(v: ParamValue) -> String {
    match v {
        ParamValue::Int(i) => i.to_string(),
        ParamValue::Float(f) => lluav_core::Number::from(f).to_string(),
    }
}
