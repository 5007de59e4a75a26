"""The type stubs: generated from the table, checked in, true to the
running package, and good enough for a type checker to catch a wrong call."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import lluav

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tools"))
import gen_stub  # noqa: E402


def test_checked_in_stubs_are_what_the_generator_writes_from_the_table():
    for path, text in gen_stub.stubs().items():
        assert path.read_text() == text, f"{path} is stale: run python python/tools/gen_stub.py"


def test_the_installed_package_ships_the_stubs():
    installed = Path(lluav.__file__).parent
    for path, text in gen_stub.stubs().items():
        assert (installed / path.name).read_text() == text
    assert (installed / "py.typed").exists()


def run_mypy(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", *args], cwd=cwd, capture_output=True, text=True)


def test_stubtest_finds_the_stubs_true_to_the_running_package(tmp_path):
    done = run_mypy("mypy.stubtest", "lluav", "--allowlist", str(HERE / "stubtest-allowlist.txt"), cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr


def test_a_type_checker_accepts_good_calls_and_flags_bad_ones(tmp_path):
    (tmp_path / "use.py").write_text(
        textwrap.dedent(
            """\
            import asyncio
            import lluav

            with lluav.Client("ws://127.0.0.1:53001", password="s3cret") as c:
                c.set_sp_ned(1.0, 2.0, -3.0, 0.5)
                c.zyhk([1.5, 2.0], land=(0.0, 0.0, 0.0))
                c.mw_exec(1001, [1, 2, 3])
                c.mission(1001, {"waypoints": []})
                c.set_param("takeoff_alt", 3.0)
                c.showmsg()
                state: dict = c.state()
                c.set_sp_ned("north", 2.0, -3.0, 0.5)  # line 12
                c.zyhk(1.5)  # line 13
                c.takeoff(3.0)  # line 14

            async def main() -> None:
                async with lluav.AsyncClient() as a:
                    r = await a.state()
                    r["ret"]
                    await a.mw_exec(1001, ["1"])  # line 20

            cmd = lluav.parse("state")
            name: str = cmd.name
            ids: list[int] = [s.id for s in lluav.COMMANDS]
            """
        )
    )
    done = run_mypy("mypy", "--no-incremental", "use.py", cwd=tmp_path)
    flagged = sorted({int(line.split(":")[1]) for line in done.stdout.splitlines() if line.startswith("use.py:")})
    assert flagged == [12, 13, 14, 20], done.stdout
