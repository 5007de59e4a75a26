"""The SDK's view of the command table, without a server: one method per
command, parameters and docs from the table, encode/parse round trips, and
local refusal of invalid arguments for every grammar."""

from __future__ import annotations

import inspect

import pytest
from values import INVALID, VALID, call_args

import lluav

GRAMMARS = sorted({spec.grammar for spec in lluav.COMMANDS})


def test_commands_are_the_table_in_id_order_with_unique_names():
    assert [spec.id for spec in lluav.COMMANDS] == list(range(1, len(lluav.COMMANDS) + 1))
    names = [spec.name for spec in lluav.COMMANDS]
    assert len(set(names)) == len(names)
    assert lluav.COMMANDS[0].name == "login"
    assert all(spec.usage.split(" ")[0] == spec.name for spec in lluav.COMMANDS)


def test_sections_follow_the_specs_command_reference():
    # The table is in the order of the spec's Command Reference, so each
    # section is one run of ids.
    sections = [spec.section for spec in lluav.COMMANDS]
    runs = [s for i, s in enumerate(sections) if i == 0 or sections[i - 1] != s]
    assert len(runs) == len(set(runs))
    assert lluav.COMMANDS[0].section == "Authentication"
    assert lluav.COMMANDS[lluav.parse("takeoff").id - 1].section == "Flight"


@pytest.mark.parametrize("cls", [lluav.Client, lluav.AsyncClient])
def test_every_command_is_a_method_with_the_table_parameters_and_docs(cls):
    for spec in lluav.COMMANDS:
        method = getattr(cls, spec.name)
        assert method.__name__ == spec.name
        assert inspect.iscoroutinefunction(method) == (cls is lluav.AsyncClient)
        params = list(inspect.signature(method).parameters.values())
        assert params[0].name == "self"
        assert [(p.name, p.default is None) for p in params[1:]] == [(p.name, p.optional) for p in spec.params]
        assert spec.summary in method.__doc__
        assert f"``{spec.usage}``" in method.__doc__


def test_gate_flags_are_said_in_the_docstring():
    for spec in lluav.COMMANDS:
        doc = lluav.Client.__dict__[spec.name].__doc__
        assert ("refused while the vehicle is armed" in doc) == (not spec.run_on_arm)
        assert ("refused in lock mode" in doc) == (not spec.run_in_lock)
        assert ("admin sessions only" in doc) == spec.admin_only


def test_every_grammar_of_the_table_has_valid_and_invalid_test_values():
    assert set(GRAMMARS) <= set(VALID), f"add values for {set(GRAMMARS) - set(VALID)} to tests/values.py"
    assert set(GRAMMARS) <= set(INVALID), f"add values for {set(GRAMMARS) - set(INVALID)} to tests/values.py"


@pytest.mark.parametrize("spec", lluav.COMMANDS, ids=lambda s: s.name)
def test_valid_arguments_encode_to_a_frame_that_parses_back_to_them(spec):
    for entry in VALID[spec.grammar]:
        args, kwargs = call_args(entry)
        frame = lluav.encode(spec.name, *args, **kwargs)
        command = lluav.parse(frame)
        assert (command.name, command.id, command.frame) == (spec.name, spec.id, frame)
        assert list(command.args) == [p.name for p in spec.params]
        assert lluav.encode(spec.name, **command.args) == frame


@pytest.mark.parametrize("spec", lluav.COMMANDS, ids=lambda s: s.name)
def test_invalid_arguments_raise_invalid_arguments_with_the_usage_line(spec):
    for entry in INVALID[spec.grammar]:
        args, kwargs = call_args(entry)
        with pytest.raises(lluav.InvalidArguments) as caught:
            lluav.encode(spec.name, *args, **kwargs)
        error = caught.value
        assert (error.name, error.usage) == (spec.name, spec.usage), entry
        assert str(error).endswith(f"; usage: {spec.usage}")
        assert isinstance(error, lluav.Error) and isinstance(error, ValueError)


def test_refusals_say_why_as_the_server_does():
    for value in ("1025", "0315"):
        with pytest.raises(lluav.InvalidArguments) as caught:
            lluav.encode("passwd", value)
        assert caught.value.reason == "the admin and logout values cannot be passwords"
    with pytest.raises(lluav.InvalidArguments) as caught:
        lluav.encode("ara8_pitch", 90.5)
    assert caught.value.reason == "angle out of range -90..90"
    with pytest.raises(lluav.InvalidArguments) as caught:
        lluav.parse("ara8_pitch 90.000001")
    assert caught.value.reason == "angle out of range -90..90"
    with pytest.raises(lluav.InvalidArguments) as caught:
        lluav.encode("set_taskname", "a\u202eb")
    assert "format characters" in caught.value.reason
    with pytest.raises(lluav.InvalidArguments) as caught:
        lluav.encode("plan", "p" * 4097)
    assert caught.value.reason == "text longer than 4096 bytes"


def test_parse_reads_frames_as_the_server_does():
    command = lluav.parse("set_sp_ned 0.1:0.2:-3.3:0.7\r\n")
    assert command.name == "set_sp_ned" and command.id == 23
    assert command.args == {"x": 0.1, "y": 0.2, "z": -3.3, "yaw": 0.7}
    assert command.frame == "set_sp_ned 0.1:0.2:-3.3:0.7"
    assert command == lluav.parse("set_sp_ned 0.1:0.2:-3.3:0.7")
    assert lluav.parse("mw_exec 1001:1,2,3,5").args == {"ext_id": 1001, "wp_ids": [1, 2, 3, 5]}
    assert lluav.parse("zyhk 1.5,2 0,0,0").args == {"heights": [1.5, 2.0], "land": (0.0, 0.0, 0.0)}
    assert lluav.parse("mission 7:maps/m.json").args == {"ext_id": 7, "payload": "maps/m.json"}
    assert lluav.parse('mission 7:{"waypoints":[]}').args == {"ext_id": 7, "payload": {"waypoints": []}}
    assert lluav.parse("set_param rtl_land:1").args == {"name": "rtl_land", "value": "1"}
    assert lluav.parse("showmsg").args == {"count": None}
    assert lluav.parse("plan  two  spaces").args == {"plan_string": " two  spaces"}


def test_parse_refuses_bad_arguments_unknown_names_and_empty_frames():
    with pytest.raises(lluav.InvalidArguments) as caught:
        lluav.parse("set_sp_ned 1:2:3")
    assert caught.value.usage == "set_sp_ned x:y:z:yaw"
    with pytest.raises(lluav.InvalidArguments):
        lluav.parse("set_sp_ned nan:0:0:0")
    with pytest.raises(lluav.UnknownCommand, match="Unsupported command: nosuch"):
        lluav.parse("nosuch 1")
    with pytest.raises(lluav.UnknownCommand, match="Empty command"):
        lluav.parse("  \r\n")
    with pytest.raises(lluav.UnknownCommand):
        lluav.encode("nosuch")


def test_numbers_travel_as_32_bit_floats_in_their_shortest_form():
    assert lluav.encode("set_sp_ned", 0.1, 0.2, -3.3, 0.7) == "set_sp_ned 0.1:0.2:-3.3:0.7"
    assert lluav.encode("set_sp_ned", 1, 2, -3, 0) == "set_sp_ned 1.0:2.0:-3.0:0.0"
    assert lluav.encode("test_wp", 1.23456789, 0, 0) == "test_wp 1.2345679:0.0:0.0"
    assert lluav.encode("set_param", "takeoff_alt", 2.5) == "set_param takeoff_alt:2.5"


class Real:
    """A number that is not a float, like numpy's float32."""

    def __init__(self, value: float) -> None:
        self.value = value

    def __float__(self) -> float:
        return self.value


class Index:
    """An integer that is not an int, like numpy's int64."""

    def __init__(self, value: int) -> None:
        self.value = value

    def __index__(self) -> int:
        return self.value


def test_numbers_may_be_any_real_or_index_type_but_not_bool_or_text():
    assert lluav.encode("set_sp_ned", Real(1.5), 0, Real(-2.0), 0.0) == "set_sp_ned 1.5:0.0:-2.0:0.0"
    assert lluav.encode("zyhk", (Real(1.5), 2), land=(Real(0.5), 0, 0)) == "zyhk 1.5,2.0 0.5,0.0,0.0"
    assert lluav.encode("mw_exec", Index(7), [Index(1), 2]) == "mw_exec 7:1,2"
    assert lluav.encode("showmsg", Index(3)) == "showmsg 3"
    for bad in [True, "1.5", b"1", None, [1.0], object()]:
        with pytest.raises(lluav.InvalidArguments, match="x (must be a number|is required)"):
            lluav.encode("set_sp_ned", bad, 0, 0, 0)
    with pytest.raises(lluav.InvalidArguments, match="must be an int, not float"):
        lluav.encode("mw_exec", 7.0, [1])
    with pytest.raises(lluav.InvalidArguments, match="must be an integer >= 0"):
        lluav.encode("mw_exec", Index(-1), [1])
    with pytest.raises(lluav.InvalidArguments, match="too large"):
        lluav.encode("set_sp_ned", 10**400, 0, 0, 0)


def test_mission_payload_is_json_for_a_dict_or_list_and_a_path_for_a_str():
    assert lluav.encode("mission", 1, {"waypoints": [{"x": 1, "y": 2, "z": -3}]}) == (
        'mission 1:{"waypoints":[{"x":1,"y":2,"z":-3}]}'
    )
    assert lluav.encode("mission", 1, [1, 2]) == "mission 1:[1,2]"
    assert lluav.encode("mission", 1, "missions/a.json") == "mission 1:missions/a.json"
    with pytest.raises(lluav.InvalidArguments, match="pass a dict or list"):
        lluav.encode("mission", 1, '{"waypoints": []}')
    nested = []
    for _ in range(70):
        nested = [nested]
    with pytest.raises(lluav.InvalidArguments):
        lluav.encode("mission", 1, nested)
