"""The README's Python scripts, run as written against a real lluavd."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time

from conftest import ROOT


def readme_scripts() -> list[str]:
    readme = (ROOT / "README.md").read_text()
    section = readme.split("\n## Python\n", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```python\n(.*?)```", section, flags=re.S)


def run(script: str, url: str, password: str) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, LLUAV_URL=url, LLUAV_PASSWORD=password)
    return subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)


def test_the_readme_has_a_sync_an_async_and_an_events_script():
    scripts = readme_scripts()
    assert len(scripts) == 3
    assert "lluav.Client(" in scripts[0] and "lluav.AsyncClient(" in scripts[1]
    assert "c.events()" in scripts[2]


def test_the_readme_flight_script_flies_and_lands(lluavd):
    daemon = lluavd(password="pw-readme", sim_speed=20)
    done = run(readme_scripts()[0], daemon.url, "pw-readme")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("landed at {"), done.stdout


def test_the_readme_async_script_runs(lluavd):
    daemon = lluavd(password="pw-readme")
    done = run(readme_scripts()[1], daemon.url, "pw-readme")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("disarmed {") and lines[0].endswith("parameters"), lines
    assert lines[1].startswith("set_sp_ned: ") and lines[1].endswith("usage: set_sp_ned x:y:z:yaw"), lines
    assert lines[2] == "-1 Vehicle is not flying", lines


def test_the_readme_events_script_follows_a_mission_until_the_landing(lluavd):
    import lluav

    daemon = lluavd(password="pw-readme", sim_speed=20)
    env = dict(os.environ, LLUAV_URL=daemon.url, LLUAV_PASSWORD="pw-readme")
    follower = subprocess.Popen(
        [sys.executable, "-c", readme_scripts()[2]], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert follower.stdout is not None
        # Subscribed once it says so: then the flight.
        assert follower.stdout.readline().startswith("following ws://"), follower.stderr
        with lluav.Client(daemon.url, password="pw-readme") as c:
            c.takeoff()
            c.mission(7, {"waypoints": [{"id": 1, "x": 2, "y": 0, "z": -3}, {"id": 2, "x": 2, "y": 2, "z": -3}]})
            while c.state()["state"]["fsm"] != "hover":
                time.sleep(0.02)
            c.mw_exec(7, [1, 2])
            while c.state()["state"]["fsm"] != "hover":
                time.sleep(0.02)
            c.land()
        out, err = follower.communicate(timeout=120)
    finally:
        follower.kill()
    assert follower.returncode == 0, err
    assert out.splitlines() == [
        "mission 7 started  ",
        "mission 7 reached 1 2",
        "mission 7 reached 2 2",
        "mission 7 completed  ",
        "landed",
    ], out
