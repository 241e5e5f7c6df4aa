"""The OptoForce driver: handshake on loop:// and on a fake DAQ, sensitivities, errors."""

import json
import time

import pytest
from fake_optoforce import FakeOptoForce

from frictionfit.acquisition.frames import ConfigAck, ConfigCommand, DataFrame, SerialReply
from frictionfit.acquisition.sensor import OptoForceSensor, load_sensitivity
from frictionfit.errors import AcquisitionError


@pytest.fixture
def loop():
    sensor = OptoForceSensor("loop://")
    sensor.open()
    yield sensor
    sensor.close()


def test_configure_accepts_ack_between_data_frames(loop):
    frames = [DataFrame(c, 0, (c, 0, 0)).encode() for c in range(3)]
    loop.port.write(frames[0] + ConfigAck(0).encode() + frames[1] + frames[2])
    assert loop.configure(1000, filter_code=1) == 9
    assert loop.frames_before_config == 1
    loop.start()
    time.sleep(0.1)
    assert [f.counter for f in loop.frames()] == [1, 2]  # those after the acknowledge


def test_rejected_configuration_names_the_result(loop):
    loop.port.write(ConfigAck(3).encode())
    with pytest.raises(AcquisitionError, match=r"loop://: the DAQ rejected .* result 3"):
        loop.configure(100)


def test_missing_acknowledge_times_out_in_words(loop):
    with pytest.raises(AcquisitionError, match="no configuration acknowledge within 0.5 s"):
        loop.configure(100)


def test_serial_number_found_among_data_frames(loop):
    loop.port.write(DataFrame(1, 0, (0, 0, 0)).encode() + SerialReply("DSE0A125").encode())
    assert loop.query_serial() == "DSE0A125"


@pytest.mark.parametrize(("kwargs", "words"), [
    ({"rate_hz": 500}, "rate 500 Hz is not one the DAQ offers"),
    ({"rate_hz": 1000, "filter_code": 9}, "filter code 9 unknown"),
])
def test_bad_settings_in_words(loop, kwargs, words):
    with pytest.raises(AcquisitionError, match=words):
        loop.configure(**kwargs)


def test_unopenable_port_names_it(tmp_path):
    with pytest.raises(AcquisitionError, match="nope: cannot open the port"):
        OptoForceSensor(str(tmp_path / "nope")).open()


def test_fake_daq_handshake_with_tare(tmp_path):
    with FakeOptoForce(tmp_path / "tty", serial="ISE0A129") as fake:
        sensor = OptoForceSensor(str(tmp_path / "tty"))
        sensor.open()
        try:
            assert sensor.query_serial() == "ISE0A129"
            sensor.configure(1000, filter_code=1, zero=True)
            sensor.start()
            time.sleep(0.2)
            got = sensor.frames()
        finally:
            sensor.close()
    # zeroing is 0 then 255 (reference section 6.3)
    assert fake.configs == [ConfigCommand(1, 1, 0), ConfigCommand(1, 1, 255)]
    assert len(got) > 50 and sum(f.lost_before for f in got) == 0


def test_a_reconfiguration_while_streaming_is_acknowledged_and_the_stop_still_drains(tmp_path):
    with FakeOptoForce(tmp_path / "tty", reply_delay_s=0.05) as fake:  # streams on 50 ms
        sensor = OptoForceSensor(str(tmp_path / "tty"))
        sensor.open()
        try:
            sensor.configure(1000, filter_code=2)
            sensor.start()
            time.sleep(0.2)
            sensor.reconfigure(1000, filter_code=2)  # the reader sees its acknowledge
            time.sleep(0.2)
            sensor.stop(filter_code=2)  # waits for its own acknowledge, not the earlier one
            got = sensor.frames()
        finally:
            sensor.close()
    assert fake.configs == [ConfigCommand(1, 2, 0), ConfigCommand(1, 2, 0), ConfigCommand(0, 2, 0)]
    assert len(got) == fake.frames_sent  # every frame sent before the stop is read


def test_sensitivity_file(tmp_path):
    path = tmp_path / "sens.json"
    path.write_text(json.dumps({"ISE0A129": [400.9, 400.9, 400.9], "BAD": [1, -2, 3]}))
    assert load_sensitivity(path, "ISE0A129") == (400.9, 400.9, 400.9)
    with pytest.raises(AcquisitionError, match=r"no sensitivity for sensor 'X1'.*\['BAD'"):
        load_sensitivity(path, "X1")
    with pytest.raises(AcquisitionError, match="must be positive counts per unit"):
        load_sensitivity(path, "BAD")
    with pytest.raises(AcquisitionError, match="cannot read the sensitivity file"):
        load_sensitivity(tmp_path / "missing.json", "ISE0A129")


def test_socket_url_works_like_a_port():
    """``socket://`` reaches a DAQ behind a TCP bridge (e.g. ser2net) with the same code."""
    import socket
    import threading

    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def daq():
        conn, _ = server.accept()
        with conn:
            conn.recv(64)  # the configuration
            conn.sendall(ConfigAck(0).encode() + DataFrame(5, 0, (1, 2, 3)).encode())
            time.sleep(0.3)

    thread = threading.Thread(target=daq)
    thread.start()
    sensor = OptoForceSensor(f"socket://127.0.0.1:{port}")
    try:
        sensor.open()
        sensor.configure(1000)
        sensor.start()
        time.sleep(0.1)
        assert [f.counts for f in sensor.frames()] == [(1, 2, 3)]
    finally:
        sensor.close()
        thread.join()
        server.close()


def test_real_daq_when_given_one():
    """Set FRICTIONFIT_OPTOFORCE_PORT (e.g. /dev/ttyACM0) to run this on hardware."""
    import os

    url = os.environ.get("FRICTIONFIT_OPTOFORCE_PORT")
    if not url:
        pytest.skip("no real DAQ: set FRICTIONFIT_OPTOFORCE_PORT to a port to test on hardware")
    sensor = OptoForceSensor(url)
    sensor.open()
    try:
        sensor.query_serial()
        sensor.configure(100, filter_code=4)
        sensor.start()
        time.sleep(0.5)
        frames = sensor.frames()
    finally:
        sensor.stop()
        sensor.close()
    assert 30 < len(frames) < 70 and sensor.parser.frames_corrupted == 0
