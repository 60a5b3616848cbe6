"""The serial sensor bridge: line protocol, grouping, resampling, calibration, and
end to end through a pseudo-terminal standing in for the device."""

from __future__ import annotations

import fcntl
import os
import re
import select
import struct
import termios
import time
import tty

import numpy as np
import pytest

from graphsvc.service.bridge import LineProtocol, Resampler, StaticCalibration

NAMES = ("a", "b", "c")


def _lines(t_ms, acc, fmt="%.6f") -> bytes:
    """Device lines for one sampling round: acc (S, 3)."""
    return b"".join(f"{t_ms:g},{s},{fmt % v[0]},{fmt % v[1]},{fmt % v[2]}\n".encode() for s, v in enumerate(acc))


def test_lines_group_into_samples():
    p = LineProtocol(NAMES, rate_hz=10.0)
    acc = np.arange(9.0).reshape(3, 3)
    out = p.push_bytes(_lines(0, acc))
    assert len(out) == 1 and out[0][0] == 0.0
    np.testing.assert_array_equal(out[0][1], acc)
    # Sensor by name, split across reads, CRLF: one sample at 0.1 s.
    out = p.push_bytes(b"100,b,1,1,1\r\n100,a,2,2,2\n10")
    assert out == []
    out = p.push_bytes(b"0,c,3,3,3\n")
    assert [t for t, _ in out] == [0.1]
    np.testing.assert_array_equal(out[0][1], [[2, 2, 2], [1, 1, 1], [3, 3, 3]])
    # A round missing sensor c ends when a later time arrives: c is missing (NaN).
    p.push_bytes(b"200,0,1,1,1\n200,1,1,1,1\n")
    out = p.push_bytes(b"300,0,5,5,5\n")
    assert [t for t, _ in out] == [0.2] and np.isnan(out[0][1][2]).all() and p.stats.incomplete_samples == 1
    assert p.stats.corrupt_lines == 0


def test_corrupt_lines_are_counted_and_skipped():
    p = LineProtocol(NAMES, rate_hz=10.0)
    good = _lines(0, np.ones((3, 3)))
    junk = (
        b"garbage\n"
        b"1,2,3\n"
        b"0,7,1,1,1\n"
        b"0,zz,1,1,1\n"
        b"x,0,1,1,1\n"
        b"0,0,nan,1,1\n"
        b"0,0,inf,1,1\n"
        b"\xff\xfe,0,1,1,1\n" + b"9" * 300 + b"\n"
        b"# banner lines are not corrupt\n\n"
    )
    out = p.push_bytes(junk + good + b"0,0,1,1,1\n" + _lines(100, np.ones((3, 3)))[:20] + b"\n")
    assert len(out) == 1  # the one good round
    assert p.stats.corrupt == {
        "wrong field count": 3,
        "unknown sensor": 2,
        "not a number": 1,
        "NaN or infinite value": 2,
        "not ASCII": 1,
        "line too long": 1,
        "time out of order": 1,
    }
    p.push_bytes(b"100,0,1,1,1\n100,0,2,2,2\n")  # a sensor twice in one round
    assert p.stats.corrupt["sensor twice in one sample"] == 1
    p.push_bytes(b"200,0,1,1")
    p.finish()
    assert p.stats.corrupt["unterminated last line"] == 1


def test_units_g():
    p = LineProtocol(NAMES, rate_hz=10.0, units="g")
    ((_, acc),) = p.push_bytes(_lines(0, np.full((3, 3), 2.0)))
    np.testing.assert_allclose(acc, 2 * 9.81)


def test_resampler_lands_on_the_graph_grid():
    r = Resampler(30.0)
    t_in = np.arange(0, 2.0, 1 / 100)  # 100 Hz device
    out = []
    for t in t_in:
        out += r.add(t, np.full((1, 3), 5.0 * t))  # a ramp: linear interpolation is exact
    times = np.array([t for t, _ in out])
    np.testing.assert_allclose(times, np.arange(len(times)) / 30.0, atol=1e-12)
    np.testing.assert_allclose([a[0, 0] for _, a in out], 5.0 * times, atol=1e-9)
    # A silence longer than 0.5 s is not bridged.
    gap = r.add(3.0, np.zeros((1, 3)))
    assert np.isnan(gap[0][1]).all() and not np.isnan(gap[-1][1]).any()


def test_calibration_estimates_constant_bias():
    expected = np.array([[0, 0, 9.81], [-9.81, 0, 0], [9.81, 0, 0]])
    bias = np.array([[0.3, -0.2, 0.1], [0.0, 0.4, -0.5], [-0.25, 0.0, 0.0]])
    cal = StaticCalibration(1.0, expected, NAMES)
    p = LineProtocol(NAMES, rate_hz=30.0, calibration=cal)
    rng = np.random.default_rng(0)
    streamed = []
    for k in range(90):  # 60 Hz: 1 s still, then 0.5 s of something else
        still = k < 60
        true = expected if still else expected + 1.0
        streamed += p.push_bytes(_lines(1000 * k / 60, true + bias + rng.normal(0, 0.02, (3, 3))))
    assert cal.done and not cal.warnings
    np.testing.assert_allclose(cal.bias, bias, atol=0.02)
    assert p.stats.calibration_samples == 60
    np.testing.assert_allclose(streamed[0][1], expected + 1.0, atol=0.1)  # corrected readings


def test_calibration_warns_when_not_still():
    expected = np.array([[0, 0, 9.81]] * 3)
    cal = StaticCalibration(0.5, expected, NAMES)
    for k in range(40):
        cal.add(k / 60, expected + (np.array([[3.0, 0, 0], [0, 0, 0], [0, 0, 0]]) if k % 2 else 0))
    assert any(w.startswith("a: moved") for w in cal.warnings)


# ---------------------------------------------------------------- end to end


def _write_all(fd, data: bytes) -> None:
    view = memoryview(data)
    while view:
        _, writable, _ = select.select([], [fd], [], 5.0)
        assert writable, "the bridge stopped reading"
        view = view[os.write(fd, view[:1024]) :]


def _unread(fd) -> int:
    return struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]


def test_bridge_end_to_end_through_a_pty(server, graph, recording, tmp_path, vmc_receiver):
    from graphsvc.motion.bvh import read_bvh
    from graphsvc.pipeline import Options, open_session
    from graphsvc.service.convert import rest_pose_readings
    from tests.service.conftest import popen_cli, wait_for

    master, slave = os.openpty()
    tty.setraw(slave)  # as pyserial will: no echo, no line editing, before the bridge opens it
    out = tmp_path / "bridge.bvh"
    proc = popen_cli(
        "sensor-bridge",
        "--device",
        os.ttyname(slave),
        "--baud",
        "115200",
        "--server",
        f"127.0.0.1:{server.port}",
        "--graph",
        "small",
        "--units",
        "g",
        "--calibrate-seconds",
        "0.5",
        "--latency",
        "0.3",
        "-o",
        out,
        "--vmc",
        f"127.0.0.1:{vmc_receiver.port}",
    )
    try:
        first = proc.stdout.readline()
        assert first.startswith("sensor-bridge: reading"), first + proc.stderr.read()

        # The device: 0.5 s still in the rest pose, then the recording, in g, with a
        # constant bias per sensor and a few corrupt lines mixed in.
        rest = rest_pose_readings(graph).astype(np.float64)
        S = rest.shape[0]
        bias = np.linspace(-0.3, 0.3, S * 3).reshape(S, 3)
        data = bytearray(b"# device banner\n")
        period_ms = 1000 / 30
        for k in range(15):
            data += _lines(k * period_ms, (rest + bias) / 9.81, "%.7f")
        for k in range(recording.num_samples):
            data += _lines((15 + k) * period_ms, (recording.accelerations[k] + bias) / 9.81, "%.7f")
            if k in (10, 40, 70):
                data += b"oops,1\n"
        _write_all(master, bytes(data))
        deadline = time.monotonic() + 10
        while _unread(slave) and time.monotonic() < deadline:  # let the bridge read it all
            time.sleep(0.02)
        time.sleep(0.2)
        os.close(master)  # the device goes away: end of input
        master = None
        stdout, stderr = proc.communicate(timeout=30)
    finally:
        if master is not None:
            os.close(master)
        os.close(slave)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stdout + stderr
    assert "3 corrupt skipped (3 wrong field count)" in stdout
    assert f"sensor-bridge: vmc: {recording.num_samples} frames sent to 127.0.0.1:{vmc_receiver.port}" in stdout
    wait_for(lambda: len(vmc_receiver.frames) == recording.num_samples)  # (each frame out as it came)
    assert f"→ {recording.num_samples} samples at 30 Hz" in stdout
    got_bias = np.array(
        [float(v) for v in re.findall(r"[+-]\d+\.\d+", stdout.split("calibration bias m/s²:")[1].splitlines()[0])]
    )
    np.testing.assert_allclose(got_bias.reshape(S, 3), bias, atol=0.006)

    # The motion written is what a live session makes of the corrected samples.
    motion = read_bvh(out)
    session = open_session(graph, Options(latency_s=0.3), graph.sensor_names)
    t = recording.timestamps_s + 15 / 30
    expected = []
    for k in range(recording.num_samples):
        expected += session.push(t[k], recording.accelerations[k])
    expected += session.flush()
    assert motion.num_frames == len(expected) == recording.num_samples
    exp_rot = np.array([f.rotations for f in expected])
    # Same poses, up to the BVH's 9-digit Euler angles (q and −q are one rotation).
    dots = np.abs(np.sum(motion.rotations * exp_rot, axis=-1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-6)


def test_a_mounting_calibration_turns_every_sample_into_the_layout_frames():
    from graphsvc.motion import quat

    mounting = quat.from_axis_angle(np.array([[1.0, 0, 0], [0, 1.0, 0], [0.6, 0, 0.8]]), np.array([0.3, -1.2, 2.0]))
    p = LineProtocol(NAMES, rate_hz=10.0, mounting=mounting)
    device = np.array([[0.0, 9.81, 0.0], [1.0, 2.0, 3.0], [-4.0, 0.5, 9.0]])
    ((_, acc),) = p.push_bytes(_lines(0, device))
    np.testing.assert_allclose(acc, quat.rotate(mounting, device), atol=1e-5)
    assert np.linalg.norm(acc, axis=-1) == pytest.approx(np.linalg.norm(device, axis=-1), abs=1e-5)
