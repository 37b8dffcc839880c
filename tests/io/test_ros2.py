"""The bulk CDR codec against mcap_ros2's own encoder and decoder (an independent implementation)."""

import numpy as np
import pytest
from mcap_ros2._dynamic import generate_dynamic, serialize_dynamic

from pendsim_bridge.io import ros2

RNG = np.random.default_rng(0)


def _codec(name):
    text = ros2.SCHEMAS[name].decode()
    return serialize_dynamic(name, text)[name], generate_dynamic(name, text)[name]


def test_imu_bytes_equal_mcap_ros2_encoding():
    encode, _ = _codec("sensor_msgs/msg/Imu")
    layout = ros2.imu_layout("imu_m1")
    n = 5
    values = {
        "sec": RNG.integers(0, 2**31 - 1, n),
        "nanosec": RNG.integers(0, 10**9, n),
        "orientation": RNG.normal(size=(n, 4)),
        "orientation_covariance": RNG.normal(size=(n, 9)),
        "angular_velocity": RNG.normal(size=(n, 3)),
        "angular_velocity_covariance": RNG.normal(size=(n, 9)),
        "linear_acceleration": RNG.normal(size=(n, 3)),
        "linear_acceleration_covariance": RNG.normal(size=(n, 9)),
    }
    ours = layout.encode(n, **values)
    for i in range(n):
        q, w, a = values["orientation"][i], values["angular_velocity"][i], values["linear_acceleration"][i]
        msg = {
            "header": {
                "stamp": {"sec": int(values["sec"][i]), "nanosec": int(values["nanosec"][i])},
                "frame_id": "imu_m1",
            },
            "orientation": dict(zip("xyzw", q, strict=True)),
            "orientation_covariance": list(values["orientation_covariance"][i]),
            "angular_velocity": dict(zip("xyz", w, strict=True)),
            "angular_velocity_covariance": list(values["angular_velocity_covariance"][i]),
            "linear_acceleration": dict(zip("xyz", a, strict=True)),
            "linear_acceleration_covariance": list(values["linear_acceleration_covariance"][i]),
        }
        assert bytes(encode(msg)) == ours[i].tobytes()
    decoded = layout.decode(ours)
    np.testing.assert_array_equal(decoded["angular_velocity"], values["angular_velocity"])


def test_joint_state_tf_vector_and_multiarray_decode_with_mcap_ros2():
    cases = [
        (
            "sensor_msgs/msg/JointState",
            ros2.joint_state_layout(("hinge_phi1", "hinge_phi2")),
            {"sec": [3], "nanosec": [4], "position": [[0.1, -0.2]], "velocity": [[1.5, 2.5]], "effort": [[-3.0, 4.0]]},
            lambda m: (m.name, m.position, m.velocity, m.effort, m.header.stamp.sec),
            (["hinge_phi1", "hinge_phi2"], [0.1, -0.2], [1.5, 2.5], [-3.0, 4.0], 3),
        ),
        (
            "tf2_msgs/msg/TFMessage",
            ros2.tf_layout((("world", "m1"), ("world", "m2"))),
            {
                **{"t0_sec": [1], "t0_nanosec": [2], "t0_translation": [[0, 0, 0]], "t0_rotation": [[0, -0.5, 0, 0.8]]},
                **{"t1_sec": [1], "t1_nanosec": [2], "t1_translation": [[1, 2, 3]], "t1_rotation": [[0, 0, 0, 1]]},
            },
            lambda m: (
                m.transforms[1].child_frame_id,
                m.transforms[0].transform.rotation.y,
                m.transforms[1].transform.translation.z,
            ),
            ("m2", -0.5, 3.0),
        ),
        (
            "geometry_msgs/msg/Vector3Stamped",
            ros2.vector3_stamped_layout("imu_m2"),
            {"sec": [7], "nanosec": [8], "vector": [[0.5, 9.81, -0.1]]},
            lambda m: (m.header.frame_id, m.vector.y),
            ("imu_m2", 9.81),
        ),
        (
            "std_msgs/msg/UInt8MultiArray",
            ros2.uint8_multiarray_layout(4),
            {"data_offset": [0], "data": [[3, 2, 1, 0]]},
            lambda m: (bytes(m.data), m.layout.dim),
            (b"\x03\x02\x01\x00", []),
        ),
    ]
    for name, layout, values, extract, expected in cases:
        _, decode = _codec(name)
        payload = layout.encode(1, **values)
        assert extract(decode(payload[0].tobytes())) == expected, name


def test_decode_refuses_a_payload_with_another_frame_id():
    layout = ros2.imu_layout("imu_m1")
    other = ros2.imu_layout("imu_m9")
    zeros = {name: 0 for name in layout.dtype.names}
    with pytest.raises(ValueError, match="does not match the fixed layout"):
        layout.decode(other.encode(1, **zeros))


@pytest.mark.parametrize(
    "statuses",
    [
        [],
        [ros2.DiagnosticStatus(0, "", "", "", ())],
        [
            ros2.DiagnosticStatus(
                1, "node m1: acquisition", "5 lost", "m1@5601", (("received", "1000"), ("lost", "5"))
            ),
            ros2.DiagnosticStatus(2, "n\u00f6de \u2202", "x" * 1001, "m2", (("k" * 3, ""),)),
        ],
    ],
)
def test_diagnostic_arrays_equal_mcap_ros2_encoding_and_decode_in_rosbags(statuses):
    from rosbags.typesys import Stores, get_typestore

    name = "diagnostic_msgs/msg/DiagnosticArray"
    encode, decode = _codec(name)
    t_ns = 1_700_000_000_123_456_789
    raw = ros2.encode_diagnostic_array(t_ns, statuses)
    as_dicts = [
        {"level": s.level, "name": s.name, "message": s.message, "hardware_id": s.hardware_id,
         "values": [{"key": k, "value": v} for k, v in s.values]}
        for s in statuses
    ]  # fmt: skip
    header = {"stamp": {"sec": t_ns // 10**9, "nanosec": t_ns % 10**9}, "frame_id": ""}
    assert raw == bytes(encode({"header": header, "status": as_dicts}))
    msg = get_typestore(Stores.ROS2_HUMBLE).deserialize_cdr(raw, name)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (t_ns // 10**9, t_ns % 10**9)
    got = [
        (s.level, s.name, s.message, s.hardware_id, tuple((kv.key, kv.value) for kv in s.values)) for s in msg.status
    ]
    assert got == [(s.level, s.name, s.message, s.hardware_id, s.values) for s in statuses]
    assert decode(raw).status[-1].name == statuses[-1].name if statuses else decode(raw).status == []
