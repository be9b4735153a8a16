"""MQTT: the bridge to a broker, the JSON request format, and the world-setting topics.

* :mod:`.bridge` -- ``--mqtt URL``: state, events and requests through a real broker (aiomqtt)
* :mod:`.requests` -- TMCL requests and replies as JSON (mnemonics or numbers)
* :mod:`.world_topics` -- ``PREFIX/A/sim/...``: switches, load, slip and inputs from outside

docs/mqtt.md documents topics and payloads.  This file imports no MQTT library.
"""

#: At most this many state messages per module and second, unless ``--mqtt-rate`` says otherwise.
DEFAULT_RATE_HZ = 10.0
