//! The commands that wait for the autopilot, as async sequences run on
//! the link's tasks: what they change on the vehicle's side (the mission
//! on the autopilot, the run, the setpoint stream) they record in what the
//! link knows themselves, so a client that leaves early loses nothing,
//! and each ends with its own [`Answer`].

use std::sync::Arc;

#[allow(deprecated)]
use ::mavlink::dialects::ardupilotmega::MISSION_SET_CURRENT_DATA;
use ::mavlink::dialects::ardupilotmega::{MISSION_ITEM_INT_DATA, MavCmd, MavMessage};

use super::answer::{
    Acknowledged, Answer, Disarmed, Following, Param, Params, Returning, Started, TookOff, Uploaded,
};
use super::autopilot::{self, Flavour, Mode, ParamValue, Phase};
use super::effect::Effect;
use super::error::MavError;
use super::link::{Link, SETPOINT_PERIOD};
use super::mission::{Mission, OnAutopilot};
use super::protocol::{self, Port};
use super::state::Known;

/// `MAV_CMD_COMPONENT_ARM_DISARM` param 2 that forces a disarm.
const FORCE_DISARM: f32 = 21196.0;

/// What a command changed, recorded once it is done; `then` makes the
/// answer from what lluavd knows at that time (`now_ms`).
pub trait Then<A>: FnOnce(&mut Known, i64) -> A + Send + 'static {}

impl<A, F: FnOnce(&mut Known, i64) -> A + Send + 'static> Then<A> for F {}

/// Runs `cmd` with the command protocol (a lost acknowledgement resolved
/// by `effect`); once done, `then` records what it changed and makes the
/// answer.
pub async fn command<A: Answer>(
    link: Arc<Link>,
    cmd: MavCmd,
    params: [f32; 7],
    effect: Option<Effect>,
    then: impl Then<A>,
) -> Result<A, MavError> {
    link.command(cmd, params, effect).await?;
    let now = link.now_ms();
    Ok(link.with(|k| then(k, now)))
}

/// `rtl`'s answer: home, and the altitude the autopilot's return climbs
/// to if lower (its own parameter; lluavd cannot clip it). ArduPilot's
/// `RTL_ALT` 0 returns at the altitude it flies at.
pub fn returning(known: &mut Known, now_ms: i64) -> Returning {
    let tel = known.tel();
    let return_alt = match (tel.flavour(), tel.rtl_alt()) {
        (Some(Flavour::ArduPilot), Some(0.0)) => tel.altitude(),
        (_, alt) => alt,
    };
    Returning {
        fsm: known.fsm(now_ms),
        home: tel.home_local(),
        return_alt,
    }
}

/// `mrtl`'s answer: home; SMART_RTL flies back along the path flown, with
/// no altitude of its own to climb to.
pub fn retracing(known: &mut Known, now_ms: i64) -> Returning {
    Returning {
        fsm: known.fsm(now_ms),
        home: known.tel().home_local(),
        return_alt: None,
    }
}

/// The answer of a command whose response is the state it left.
pub fn acknowledged(known: &mut Known, now_ms: i64) -> Acknowledged {
    Acknowledged {
        fsm: known.fsm(now_ms),
    }
}

/// `land`'s answer: a vehicle that just took off no longer counts as
/// flying on lluavd's word (the telemetry tells), and the state it left.
pub fn landing(known: &mut Known, now_ms: i64) -> Acknowledged {
    known.landing();
    acknowledged(known, now_ms)
}

/// Switches the flight mode for a motion command (`takeoff`,
/// `set_sp_ned`): never out of a failsafe that holds (DESIGN.md, "Flight
/// authority"; `mrtl`, a conservative command, sends its own).
pub async fn set_mode(link: &Link, flavour: Flavour, mode: Mode) -> Result<(), MavError> {
    let [p1, p2, p3] = flavour.set_mode_params(mode).ok_or(MavError::Unsupported)?;
    link.with(|k| k.check_steering())?;
    let params = [p1, p2, p3, 0.0, 0.0, 0.0, 0.0];
    link.command(
        MavCmd::MAV_CMD_DO_SET_MODE,
        params,
        Some(Effect::Mode(flavour, mode)),
    )
    .await
}

/// Arms and takes off to `alt` metres above home. ArduPilot is put in
/// GUIDED first. A takeoff the autopilot refuses disarms again rather
/// than leave an armed vehicle on the ground; one whose acknowledgement
/// never came is left alone (the vehicle may be climbing). Once it
/// answers 0, the vehicle counts as flying.
pub async fn takeoff(link: Arc<Link>, flavour: Flavour, alt: f32) -> Result<TookOff, MavError> {
    if flavour == Flavour::ArduPilot {
        set_mode(&link, flavour, Mode::Guided).await?;
    }
    let arm = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    link.command(
        MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
        arm,
        Some(Effect::Armed(true)),
    )
    .await?;
    link.with(|k| k.check_steering())?;
    // PX4 takes the takeoff altitude above mean sea level; ArduPilot above
    // home. NaN lets PX4 use its own MIS_TAKEOFF_ALT when home is unknown.
    let param7 = match (flavour, link.with(|k| k.tel().home_global())) {
        (Flavour::ArduPilot, _) => alt,
        (_, Some(home)) => (home.alt + f64::from(alt)) as f32,
        (_, None) => f32::NAN,
    };
    let nan = f32::NAN;
    let params = [0.0, 0.0, 0.0, nan, nan, nan, param7];
    let airborne = Some(Effect::Airborne(flavour));
    match link.command(MavCmd::MAV_CMD_NAV_TAKEOFF, params, airborne).await {
        Ok(()) => {
            let now = link.now_ms();
            link.with(|k| k.took_off(now));
            Ok(TookOff { target_alt: alt })
        }
        Err(refused @ MavError::Refused { .. }) => {
            // The autopilot said no: the vehicle is armed on the ground.
            let disarm = [0.0; 7];
            let disarmed = Some(Effect::Armed(false));
            if let Err(e) = link
                .command(MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, disarm, disarmed)
                .await
            {
                tracing::warn!(error = %e, "could not disarm after a refused takeoff");
            }
            Err(refused)
        }
        Err(e) => Err(e),
    }
}

/// Disarms at once, in the air too (the protocol's `disarm` is a force
/// disarm); the setpoint stream stops.
pub async fn disarm(link: Arc<Link>) -> Result<Disarmed, MavError> {
    link.with(Known::stop_stream);
    let params = [0.0, FORCE_DISARM, 0.0, 0.0, 0.0, 0.0, 0.0];
    let disarmed = Some(Effect::Armed(false));
    command(
        link,
        MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
        params,
        disarmed,
        |k, _| {
            k.disarmed();
            Disarmed
        },
    )
    .await
}

/// Puts the autopilot in the mode that follows the (already streaming)
/// setpoint. The stream stops if the autopilot refuses.
pub async fn follow_setpoints(link: Arc<Link>, flavour: Flavour) -> Result<Following, MavError> {
    // PX4 refuses offboard unless setpoints already arrive: let a few go.
    tokio::time::sleep(SETPOINT_PERIOD * 3).await;
    match set_mode(&link, flavour, Mode::Guided).await {
        Ok(()) => {
            let now = link.now_ms();
            Ok(link.with(|k| k.following(now)))
        }
        Err(e) => {
            link.with(Known::stop_stream);
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
) -> Result<Uploaded, MavError> {
    if let Err(e) = protocol::upload_mission(&*link, link.timing(), &items).await {
        link.with(|k| k.missions_mut().upload_failed());
        return Err(e);
    }
    let answer = Uploaded {
        ext_id: mission.ext_id,
        waypoints: mission.waypoints.len(),
        items: items.len(),
    };
    link.with(|k| k.missions_mut().uploaded(mission, first_seq));
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
) -> Result<Started, MavError> {
    if let Some(items) = items {
        if let Err(e) = protocol::upload_mission(&*link, link.timing(), &items).await {
            link.with(|k| k.missions_mut().upload_failed());
            return Err(e);
        }
        link.with(|k| k.missions_mut().holds(plan.clone()));
    }
    let target = link.target()?;
    link.with(|k| k.check_steering())?;
    link.send(MavMessage::MISSION_SET_CURRENT(MISSION_SET_CURRENT_DATA {
        seq: plan.first_seq,
        target_system: target.system,
        target_component: target.component,
    }))
    .await?;
    let answer = Started {
        ext_id: plan.ext_id,
        wp_ids: plan.wp_ids.clone(),
    };
    link.with(|k| {
        k.stop_stream();
        k.missions_mut().start_run(plan);
    });
    let flying = link
        .with(|k| k.tel().flavour())
        .map(|f| Effect::Phase(f, Phase::Mission));
    if let Err(e) = link
        .command(MavCmd::MAV_CMD_MISSION_START, [0.0; 7], flying)
        .await
    {
        link.with(|k| k.missions_mut().drop_run());
        return Err(e);
    }
    let now = link.now_ms();
    link.with(|k| k.mission_started(now));
    Ok(answer)
}

/// Reads a parameter.
pub async fn get_param(link: Arc<Link>, name: String) -> Result<Param, MavError> {
    let v = protocol::read_param(&*link, link.timing(), &name).await?;
    let value = link
        .with(|k| k.tel().encoding())
        .decode(v.param_type, v.param_value);
    Ok(Param {
        name,
        value,
        ty: v.param_type,
        index: v.param_index,
        count: v.param_count,
    })
}

/// Reads every parameter.
pub async fn all_params(link: Arc<Link>) -> Result<Params, MavError> {
    let values = protocol::read_all_params(&*link, link.timing()).await?;
    let encoding = link.with(|k| k.tel().encoding());
    Ok(Params(
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
pub async fn set_param(link: Arc<Link>, name: String, text: String) -> Result<Param, MavError> {
    let current = protocol::read_param(&*link, link.timing(), &name).await?;
    let ty = current.param_type;
    let value = autopilot::parse_value(&name, ty, &text).map_err(MavError::Invalid)?;
    let encoding = link.with(|k| k.tel().encoding());
    let echo = protocol::write_param(&*link, link.timing(), &name, encoding.encode(ty, value), ty).await?;
    let got = encoding.decode(echo.param_type, echo.param_value);
    if got != value {
        return Err(MavError::State(format!(
            "the autopilot kept {name} at {}",
            show(got)
        )));
    }
    Ok(Param {
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
