"""ROS 1 / ROS 2 bags written with rosbags' own writers, read back through the bluerov2-mavros mapping."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from udrobot_ctrl.convert import convert_log, load_any
from udrobot_ctrl.io import LogImportError
from udrobot_ctrl.io.rosbag import MAVROS_MSGS
from udrobot_ctrl.io.runlog import read_run, write

A = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # ENU <-> NED
B = np.diag([1.0, -1.0, -1.0])  # FLU <-> FRD
DELAY = 0.05  # s, header stamp -> bag record time


def truth(t):
    """NED/FRD attitude, body rates (any consistent values; the mapping is a pure frame change), depth, PWM."""
    phi = 0.3 * np.sin(2 * np.pi * 0.5 * t)
    theta = 0.1 + 0.05 * np.cos(2 * np.pi * 0.3 * t)
    psi = 3.0 + 0.4 * t  # crosses +pi: wrapping must be handled
    pqr = np.stack([np.cos(t), 0.2 * np.sin(t), -0.3 + 0 * t], -1)
    depth = 0.5 + 0.1 * t
    return phi, theta, psi, pqr, depth


def _typestore(ros1: bool):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    types = {}
    for name, text in MAVROS_MSGS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def _messages(store, t_imu, t_rc):
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    Quat, Vec = T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Vector3"]

    def header(t):
        sec = int(np.floor(t))
        stamp = Time(sec=sec, nanosec=int(round((t - sec) * 1e9)))
        if "seq" in Header.__dataclass_fields__:  # ROS 1 header
            return Header(seq=0, stamp=stamp, frame_id="base_link")
        return Header(stamp=stamp, frame_id="base_link")

    phi, theta, psi, pqr, depth = truth(t_imu - T0)
    for k, t in enumerate(t_imu):
        R_ned = Rotation.from_euler("ZYX", [psi[k], theta[k], phi[k]]).as_matrix()
        qx, qy, qz, qw = Rotation.from_matrix(A @ R_ned @ B).as_quat()
        w_flu = B @ pqr[k]
        imu = T["sensor_msgs/msg/Imu"](header=header(t), orientation=Quat(x=qx, y=qy, z=qz, w=qw),
                                       orientation_covariance=np.zeros(9), angular_velocity=Vec(*w_flu),
                                       angular_velocity_covariance=np.zeros(9),
                                       linear_acceleration=Vec(0.0, 0.0, 9.81),
                                       linear_acceleration_covariance=np.zeros(9))
        yield "/mavros/imu/data", "sensor_msgs/msg/Imu", t + DELAY, imu
        yield "/mavros/global_position/rel_alt", "std_msgs/msg/Float64", t + DELAY, \
            T["std_msgs/msg/Float64"](data=-depth[k])
    for k, t in enumerate(t_rc):
        rc = T["mavros_msgs/msg/RCOut"](header=header(t), channels=np.array([1500 + k, 1400, 1600, 1500 - k, 1500,
                                                                             1500], dtype=np.uint16))
        yield "/mavros/rc/out", "mavros_msgs/msg/RCOut", t + DELAY, rc


def write_bag(path, kind, t_imu, t_rc):
    """Write a bag of kind 'ros1' | 'sqlite3' | 'mcap' with rosbags' writer."""
    ros1 = kind == "ros1"
    store = _typestore(ros1)
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)
    msgs = sorted(_messages(store, t_imu, t_rc), key=lambda m: m[2])
    with writer:
        conns = {}
        for topic, msgtype, stamp, msg in msgs:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
            data = store.serialize_ros1(msg, msgtype) if ros1 else store.serialize_cdr(msg, msgtype)
            writer.write(conns[topic], int(round(stamp * 1e9)), data)
    return path


T0 = 1_700_000_000.0


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap"])
def test_bag_round_trip_through_mavros_mapping(tmp_path, kind):
    t_imu = T0 + np.arange(0.0, 4.0, 0.02)  # 50 Hz
    t_rc = T0 + 0.013 + np.arange(0.0, 4.0, 0.1)  # 10 Hz commands
    path = write_bag(tmp_path / ("run.bag" if kind == "ros1" else "run2"), kind, t_imu, t_rc)
    run = convert_log(path, "bluerov2-mavros")
    # time base: 50 Hz over the overlap of all streams. rel_alt (Float64) has no header, so it is on the bag
    # record clock and starts at T0 + DELAY: the latest first sample
    assert run.dt_median == pytest.approx(0.02, rel=1e-9)
    t_abs = run.extra["t_source"]  # last imu header stamp at or before each sample
    t_grid = T0 + DELAY + run.t
    assert np.all(t_abs <= t_grid + 1e-6) and np.all(t_grid - t_abs < 0.02 + 1e-6)
    phi, theta, psi, pqr, depth = truth(t_grid - T0)
    # linear interpolation of smooth signals at 50 Hz: error <= max|y''| dt^2 / 8
    np.testing.assert_allclose(run.channels["phi"], phi, atol=0.3 * (np.pi) ** 2 * 0.02**2 / 8 + 1e-6)
    np.testing.assert_allclose(run.channels["theta"], theta, atol=1e-4)
    wrapped = np.angle(np.exp(1j * (run.channels["psi"] - psi)))
    assert np.max(np.abs(wrapped)) < 1e-6
    np.testing.assert_allclose(np.column_stack([run.channels[c] for c in "pqr"]), pqr, atol=1e-3)
    np.testing.assert_allclose(run.channels["z"], depth - 0.1 * DELAY, atol=1e-6)  # depth logged DELAY late
    # zero-order hold of the commands: the command in force is the last one at or before t
    k = np.floor((t_grid - T0 - 0.013) / 0.1 + 1e-9).astype(int)
    np.testing.assert_array_equal(run.inputs[:, 0], 1500 + k)
    np.testing.assert_array_equal(run.inputs[:, 3], 1500 - k)
    assert run.input_kind == "pwm" and run.inputs.shape[1] == 4
    notes = run.metadata["notes"]
    assert "/mavros/imu/data: bag record time - header.stamp delay median 50.0 ms" in notes
    assert "not in this log" in notes and "u" in notes
    # written and read back as udrobot-run/1
    out = write(run, tmp_path / "out.csv")
    back = read_run(out)
    assert back.n == run.n and back.metadata["notes"] == notes
    # load_any dispatches on the type
    assert load_any(path).n == run.n


def test_corrupt_and_truncated_bags_fail_loudly(tmp_path):
    t = T0 + np.arange(0.0, 2.0, 0.02)
    path = write_bag(tmp_path / "r.bag", "ros1", t, t)
    data = path.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(LogImportError, match="cut.bag"):
        convert_log(cut, "bluerov2-mavros")
    garbage = tmp_path / "garbage.bag"
    garbage.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 8)
    with pytest.raises(LogImportError, match="garbage.bag"):
        convert_log(garbage, "bluerov2-mavros")
    # a ROS 2 mcap bag with its message data overwritten mid-file
    p2 = write_bag(tmp_path / "r2", "mcap", t, t)
    mcap = next(p2.glob("*.mcap"))
    raw = bytearray(mcap.read_bytes())
    mid = len(raw) // 2
    raw[mid: mid + 64] = b"\xff" * 64
    mcap.write_bytes(bytes(raw))
    with pytest.raises(LogImportError, match=r"r2"):
        convert_log(p2, "bluerov2-mavros")


def test_missing_input_topic_is_an_error_unless_allowed(tmp_path):
    t = T0 + np.arange(0.0, 1.0, 0.02)
    path = write_bag(tmp_path / "r.bag", "ros1", t, np.array([]))
    with pytest.raises(LogImportError, match="pwm_1.*not found in the log"):
        convert_log(path, "bluerov2-mavros")
    run = convert_log(path, "bluerov2-mavros", require_inputs=False)
    assert np.isnan(run.inputs).all() and run.n == 47  # overlap of imu (header) and rel_alt (record +50 ms)
    assert "inputs not in this log" in run.metadata["notes"]
