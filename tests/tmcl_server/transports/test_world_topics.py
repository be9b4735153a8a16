"""``sim/...`` messages (the MQTT bridge's world controls) applied to a module directly."""

from __future__ import annotations

import pytest

from tmcl_server.module import TMCM6212
from tmcl_server.transports.mqtt.world_topics import WorldTopicError, apply_sim_message


@pytest.fixture
def module() -> TMCM6212:
    return TMCM6212()


def test_inputs_digital_and_analog(module):
    apply_sim_message(module, ["input", "2"], b"true")
    apply_sim_message(module, ["input", "3"], b'{"analog": 1234}')
    assert module.digital_input(2) == 1 and module.analog_inputs[3] == 1234
    apply_sim_message(module, ["input", "2"], b"off")
    assert module.digital_input(2) == 0


def test_switch_forced_placed_and_removed(module):
    apply_sim_message(module, ["switch", "1", "home"], b"1")
    assert module.axis(1).status().home_switch
    apply_sim_message(module, ["switch", "1", "home"], b"null")
    assert not module.axis(1).status().home_switch
    apply_sim_message(module, ["switch", "1", "right"], b'{"position": -10, "side": "above"}')
    assert module.axis(1).status().right_switch  # [-10, end of travel] covers 0
    assert module.axis_world(1).switches["right"].low == -10


def test_load_and_encoder_slip(module):
    apply_sim_message(module, ["load", "4"], b"321")
    assert module.axis(4).status().load == 321
    apply_sim_message(module, ["load", "4"], b'{"free": 600, "zones": [[-5, 5, 0]]}')
    assert module.axis(4).status().load == 0
    apply_sim_message(module, ["encoder_slip", "4"], b"0.25")
    assert module.axis_world(4).encoder_slip == 0.25


@pytest.mark.parametrize(("path", "payload", "message"), [
    (["input", "9"], b"1", "input must be 0..3"),
    (["input", "0"], b"2", "expected 0/1"),
    (["input", "0"], b'{"analog": 70000}', "analog value must be"),
    (["switch", "6", "left"], b"1", "axis must be 0..5"),
    (["switch", "0", "middle"], b"1", "switch must be one of"),
    (["switch", "0", "left"], b'{"width": 5}', "needs position"),
    (["load", "0"], b"2000", "load must be an integer 0..1023"),
    (["load", "0"], b'{"zones": [[1, 2]]}', "zones must be"),
    (["encoder_slip", "0"], b"1.5", "slip must be a number 0..1"),
    (["gravity"], b"1", "unknown sim topic"),
    (["input", "0"], b"maybe", "cannot read value"),
    (["switch", "0", "left"], b'{"position": 5, "side": "inside"}', "unknown switch side"),
    # issue 11 item 10: nothing non-finite, nothing but UTF-8, bounded nesting
    (["switch", "0", "left"], b'{"position": 1e999}', "out of range"),
    (["switch", "0", "left"], b'{"position": 2e5}', "position must be an integer"),
    (["switch", "0", "left"], b'{"position": 0, "normally_closed": "yes"}', "expected 0/1"),
    (["load", "0"], b'{"free": NaN}', "NaN is not a number"),
    (["load", "0"], b'{"zones": [[0, Infinity, 0]]}', "Infinity is not a number"),
    (["encoder_slip", "0"], b"-Infinity", "-Infinity is not a number"),
    (["supply"], b"1e400", "out of range"),
    (["input", "0"], b"\xc3\x28", "not UTF-8 text"),
    (["input", "0"], b"[" * 17 + b"]" * 17, "nested deeper than 16"),
])
def test_bad_messages_say_what_is_wrong(module, path, payload, message):
    with pytest.raises(WorldTopicError, match=message):
        apply_sim_message(module, path, payload)
