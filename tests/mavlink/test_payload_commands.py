"""Camera, gimbal, parameter storage and the autopilot's reboot: each
command reaches the autopilot as its MAV_CMD with the right parameters
(a pymavlink autopilot that acknowledges everything)."""

import math

from conftest import wait_for
from fault_autopilot import mav


def last(ap, cmd):
    return wait_for(f"command {cmd}", lambda: ap.commands(cmd))[-1]


def test_capture_takes_one_image(vehicle):
    _, ap, client = vehicle()
    assert client.ok("capture")["capture"] == {"seq": 1}
    c = last(ap, mav.MAV_CMD_IMAGE_START_CAPTURE)
    assert (c.param2, c.param3, c.param4) == (0.0, 1.0, 1.0)
    assert client.ok("capture")["capture"] == {"seq": 2}


def test_record_starts_then_stops_video(vehicle):
    _, ap, client = vehicle()
    assert client.ok("record")["recording"] is True
    last(ap, mav.MAV_CMD_VIDEO_START_CAPTURE)
    assert client.ok("record")["recording"] is False
    last(ap, mav.MAV_CMD_VIDEO_STOP_CAPTURE)


def test_gimbal_commands_go_to_the_gimbal_manager(vehicle):
    _, ap, client = vehicle()
    client.ok("ara8_pitch -30")
    c = last(ap, mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW)
    assert c.param1 == -30.0 and math.isnan(c.param2)
    client.ok("siyi_center")
    c = last(ap, mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW)
    assert (c.param1, c.param2) == (0.0, 0.0)


def test_parameter_storage_and_reboot_map_to_their_commands(vehicle):
    _, ap, client = vehicle()
    assert client.ok("save_param 1")["saved"] is True
    assert last(ap, mav.MAV_CMD_PREFLIGHT_STORAGE).param1 == 1.0
    client.ok("reset_param")
    assert last(ap, mav.MAV_CMD_PREFLIGHT_STORAGE).param1 == 2.0
    assert client.ok("reboot_ap")["reboot"] == {"target": "autopilot", "simulated": False}
    assert last(ap, mav.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN).param1 == 1.0


def test_commands_without_a_mavlink_meaning_are_refused_honestly(vehicle):
    _, _, client = vehicle()
    for cmd in ("tether_land", "wakeup", "ledon", "zyhk 2", "lidarwarn"):
        r = client.cmd(cmd)
        assert (r["ret"], r["msg"]) == (-2, "Invalid arguments: not supported by this vehicle"), (cmd, r)
    # The companion computer still answers its own commands.
    assert client.ok("machineid")["did"]
    assert "sysinfo" in client.ok("sysinfo")
