"""What real BNO055 nodes on a hand-built rig add beyond the noise model, as seeded processes.

All of it is off by default: the paper is silent on it. Each item, and how it is modelled:

- **NDOF heading**: in NDOF mode the chip references its orientation to magnetic north, so the
  quaternions' world frame is the rig's world turned by an arbitrary heading about the vertical
  (one north for both nodes).
- **Mount misalignment**: a node glued on by hand is turned by a few degrees; that is
  ``Bno055.mount_quat_wxyz`` (``random_mount`` draws one of a given angle about a random axis).
- **Axis remap** (datasheet rev 1.4, section 3.4): the AXIS_MAP_CONFIG register names, in bits
  1-0, 3-2 and 5-4, the source axis (0 x, 1 y, 2 z) of the output x, y and z; AXIS_MAP_SIGN
  negates output x, y, z with bits 2, 1, 0. Any of the 6 x 8 = 48 settings is allowed: 24 are
  rotations, 24 mirror the frame (left-handed). Vector outputs are remapped exactly (v' = P v).
  The fused quaternion of a mirrored frame cannot exist; the datasheet does not say what the chip
  reports then, and the model gives the orientation of the right-handed frame -P (all three
  remapped axes reversed). The alignment reads angles in a way that does not depend on this.
- **Fusion orientation error**: a slowly varying small-angle rotation (sensor axes) applied to
  the fused orientation, beyond the quaternion's quantisation; the gravity output is computed
  from the erroneous orientation, as the chip computes it from its own estimate.
- **Fusion phase**: where each chip's 100 Hz fusion ticks fall relative to the release.
- **Packet loss**: per node, bursty (a two-state Gilbert channel: a loss run has a geometric
  length of mean ``loss_burst_samples``; the long-run lost share is ``packet_loss``).
- **Clocks**: each node stamps its samples with its own clock, which runs ``clock_drift_ppm``
  fast and reads ``clock_offset_s`` at the recording's start; the recorder logs each message at
  its arrival, ``latency_s`` (mean of an exponential) after it was sampled.
- **Hand wobble**: while the pendulums are held before the release, the hand moves them about
  the hinge: a slow drift (0.1-2 Hz) carrying most of the given rms angle, plus physiological
  tremor (8-12 Hz) of a small share of it (``TREMOR_SHARE``: 0.02 deg rms at 1 deg, 0.1 mm at
  the bob's 0.3 m, tremor accelerations of a few 0.1 m/s^2 as in hand-held tremor studies).
  Both fade out over the last 0.5 s so the release itself is from rest. At 2 deg the held
  pendulum turns at about 0.2 rad/s rms, a tenth of a 30 deg swing's peak rate.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.errors import ParameterError
from pendsim_mj.sensors import rotations

Floats = NDArray[np.float64]

DEFAULT_AXIS_MAP_CONFIG = 0x24  # datasheet: x = x, y = y, z = z
DEFAULT_AXIS_MAP_SIGN = 0x00
WOBBLE_FADE_S = 0.5  # the hand's tremor fades out over the last 0.5 s before the release
WOBBLE_DRIFT_HZ = (0.1, 2.0)  # the hand's slow drift while holding
WOBBLE_TREMOR_HZ = (8.0, 12.0)  # physiological tremor
TREMOR_SHARE = 0.02  # tremor's rms angle as a share of the wobble's


@dataclasses.dataclass(frozen=True)
class Imperfections:
    """Imperfections of the two nodes (index 0: M1, 1: M2); see the module docstring.

    Attributes:
      heading_rad: NDOF heading: the quaternions' world frame is the rig's world turned by this
        angle about the vertical, rad.
      axis_map_config, axis_map_sign: each node's AXIS_MAP_CONFIG and AXIS_MAP_SIGN register.
      fusion_error_rad: rms per axis of the fused orientation's slowly varying error, rad.
      fusion_error_period_s: typical period of that error (its sinusoids span a third to three
        times it), s.
      fusion_phase_s: each chip's first fusion tick after the release, s, in [0, 1/fusion rate).
      packet_loss: long-run share of samples lost per node, in [0, 0.9].
      loss_burst_samples: mean length of a run of lost samples, >= 1 (1: independent losses).
      clock_drift_ppm: each node's clock rate error, ppm (node time = (1 + ppm 1e-6) true time).
      clock_offset_s: each node's clock reading at the recording's start, s (>= 0).
      latency_s: mean transport latency (exponential) from sampling to logging, s.
      hold_wobble_rad: rms angle of the hand's tremor while the pendulums are held, rad.
    """

    heading_rad: float = 0.0
    axis_map_config: tuple[int, int] = (DEFAULT_AXIS_MAP_CONFIG, DEFAULT_AXIS_MAP_CONFIG)
    axis_map_sign: tuple[int, int] = (DEFAULT_AXIS_MAP_SIGN, DEFAULT_AXIS_MAP_SIGN)
    fusion_error_rad: float = 0.0
    fusion_error_period_s: float = 30.0
    fusion_phase_s: tuple[float, float] = (0.0, 0.0)
    packet_loss: float = 0.0
    loss_burst_samples: float = 1.0
    clock_drift_ppm: tuple[float, float] = (0.0, 0.0)
    clock_offset_s: tuple[float, float] = (0.0, 0.0)
    latency_s: float = 0.0
    hold_wobble_rad: float = 0.0

    def __post_init__(self) -> None:
        for k in range(2):
            axis_remap_matrix(self.axis_map_config[k], self.axis_map_sign[k])  # raises on a bad register
        _check(self.heading_rad, "heading_rad", -math.tau, math.tau)
        _check(self.fusion_error_rad, "fusion_error_rad", 0.0, 0.2)
        _check(self.fusion_error_period_s, "fusion_error_period_s", 1.0, 1e5)
        _check(self.packet_loss, "packet_loss", 0.0, 0.9)
        _check(self.loss_burst_samples, "loss_burst_samples", 1.0, 1e4)
        _check(self.latency_s, "latency_s", 0.0, 1.0)
        _check(self.hold_wobble_rad, "hold_wobble_rad", 0.0, 0.1)
        for name in ("fusion_phase_s", "clock_drift_ppm", "clock_offset_s"):
            if len(getattr(self, name)) != 2:
                raise ParameterError(f"{name} must be two numbers (M1, M2), got {getattr(self, name)!r}")
        for value in self.fusion_phase_s:
            _check(value, "fusion_phase_s", 0.0, 1.0)
        for value in self.clock_drift_ppm:
            _check(value, "clock_drift_ppm", -1000.0, 1000.0)
        for value in self.clock_offset_s:
            _check(value, "clock_offset_s", 0.0, 1e6)

    @property
    def any_timing(self) -> bool:
        """True when a node's instants differ from the plain k / rate grid (drift, phase, offset)."""
        return any(self.clock_drift_ppm) or any(self.fusion_phase_s)


def _check(value: float, name: str, low: float, high: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and low <= value <= high):
        raise ParameterError(f"{name} must be a finite number in [{low:g}, {high:g}], got {value!r}")


def axis_remap_matrix(config: int, sign: int) -> Floats:
    """The (3, 3) signed permutation P of a BNO055 axis remap: output vector = P @ input vector.

    Args:
      config: AXIS_MAP_CONFIG (bits 1-0: source of x, 3-2: of y, 5-4: of z; 0 x, 1 y, 2 z).
      sign: AXIS_MAP_SIGN (bit 2 negates x, bit 1 y, bit 0 z).

    Raises:
      ParameterError: a register value the chip would refuse (an axis used twice, code 3, bits
        above those named).
    """
    if not (isinstance(config, int) and 0 <= config <= 0x3F):
        raise ParameterError(f"AXIS_MAP_CONFIG must be a byte 0x00-0x3F, got {config!r}")
    if not (isinstance(sign, int) and 0 <= sign <= 0x07):
        raise ParameterError(f"AXIS_MAP_SIGN must be 0x00-0x07, got {sign!r}")
    sources = [(config >> (2 * i)) & 3 for i in range(3)]
    if sorted(sources) != [0, 1, 2]:
        raise ParameterError(
            f"AXIS_MAP_CONFIG 0x{config:02X} does not name each of x, y, z once (the chip refuses it); "
            "e.g. 0x24 is the default, 0x21 swaps x and y"
        )
    p = np.zeros((3, 3))
    for i, source in enumerate(sources):
        p[i, source] = -1.0 if sign & (4 >> i) else 1.0
    return p


def all_axis_remaps() -> list[tuple[int, int]]:
    """Every (AXIS_MAP_CONFIG, AXIS_MAP_SIGN) pair the chip accepts: 6 permutations x 8 signs."""
    out = []
    for perm in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        config = perm[0] | perm[1] << 2 | perm[2] << 4
        out += [(config, sign) for sign in range(8)]
    return out


def remap_quaternion(p: Floats) -> Floats:
    """The quaternion (w, x, y, z) that turns a frame into the remapped frame: q' = q * this.
    For a mirroring P, the right-handed frame -P (see the module docstring)."""
    proper = p if np.linalg.det(p) > 0 else -p
    return rotations.from_matrix(proper.T)


def random_mount(angle_rad: float, rng: np.random.Generator) -> tuple[float, float, float, float]:
    """A mount rotation of exactly ``angle_rad`` about a random axis (uniform on the sphere)."""
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    q = rotations.from_rotvec(axis * angle_rad)
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def smooth_process(
    rng: np.random.Generator, t_s: Floats, rms: float, low_hz: float, high_hz: float, shape: tuple[int, ...]
) -> tuple[Floats, Floats, Floats]:
    """A smooth random process (a sum of 16 sinusoids per component, frequencies log-uniform in
    [low_hz, high_hz], random phases, total rms ``rms``) and its first two time derivatives at
    instants ``t_s`` (m,); each of shape (m, *shape)."""
    count = 16
    f = np.exp(rng.uniform(math.log(low_hz), math.log(high_hz), (count, *shape)))
    phase = rng.uniform(0.0, math.tau, (count, *shape))
    amplitude = rms * math.sqrt(2.0 / count)  # each sinusoid has rms A / sqrt(2)
    w = math.tau * f
    arg = w[None] * np.asarray(t_s).reshape(-1, 1, *([1] * len(shape))) + phase[None]
    value = amplitude * np.sin(arg).sum(axis=1)
    rate = amplitude * (w[None] * np.cos(arg)).sum(axis=1)
    accel = -amplitude * (w[None] ** 2 * np.sin(arg)).sum(axis=1)
    return value, rate, accel


def hold_wobble(rng: np.random.Generator, t_s: Floats, rms_rad: float) -> tuple[Floats, Floats, Floats]:
    """The held pendulums' tremor at instants ``t_s`` (m,) before the release (t < 0): angle,
    rate and angular acceleration, each (m, 2); faded to rest over the last WOBBLE_FADE_S.
    ``rms_rad`` is the total rms angle: slow drift plus a TREMOR_SHARE of it as tremor."""
    tremor_rad = TREMOR_SHARE * rms_rad
    drift = smooth_process(rng, t_s, math.sqrt(rms_rad**2 - tremor_rad**2), *WOBBLE_DRIFT_HZ, (2,))
    tremor = smooth_process(rng, t_s, tremor_rad, *WOBBLE_TREMOR_HZ, (2,))
    w, dw, ddw = (a + b for a, b in zip(drift, tremor, strict=True))
    # fade = sin^2(b t) over the last WOBBLE_FADE_S (0 with zero slope at t = 0), 1 before
    b = math.pi / (2 * WOBBLE_FADE_S)
    t = np.asarray(t_s).reshape(-1, 1)
    inside = t > -WOBBLE_FADE_S
    fade = np.where(inside, np.sin(b * t) ** 2, 1.0)
    dfade = np.where(inside, b * np.sin(2 * b * t), 0.0)
    ddfade = np.where(inside, 2 * b * b * np.cos(2 * b * t), 0.0)
    return fade * w, dfade * w + fade * dw, ddfade * w + 2 * dfade * dw + fade * ddw


def gilbert_loss(rng: np.random.Generator, m: int, share: float, burst_samples: float) -> NDArray[np.bool_]:
    """(m,) True where a sample arrives: a two-state channel whose loss runs have geometric
    lengths of mean ``burst_samples`` and whose long-run lost share is ``share``."""
    if share <= 0 or m == 0:
        return np.ones(m, dtype=bool)
    p_recover = 1.0 / burst_samples
    p_lose = share * p_recover / (1.0 - share)
    received = np.ones(m, dtype=bool)
    k = 0
    lost = rng.random() < share  # start in the stationary distribution
    while k < m:
        run = int(rng.geometric(p_recover if lost else p_lose))
        if lost:
            received[k : k + run] = False
        k += run
        lost = not lost
    return received
