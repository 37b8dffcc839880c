"""The rig as a linear system about rest, for control design: x' = A x + B u, its exact
discretisation over one control period with the inputs held (zero-order hold), and the normal
modes' amplitudes of a nonlinear run.

x = (phi1, phi2, omega1, omega2) (rad, rad/s); u = the drives' channels (``drives.Target``:
tau1, tau2 in N m, support_x, pivot_z in m/s^2). From the linearised equations of
``engines.linearised`` (M q'' + C q' + K q = tau; K = springs + gravity):

    A = [[0, I], [-M^-1 K, -M^-1 C]],   B = [[0], [M^-1 T]],

with T the moments per unit input at rest: a hinge torque acts on its own pendulum (1), a
horizontal support acceleration a_h on pendulum n as -m_n OC_n a_h cos(phi_n) -> -m_n OC_n, and
a vertical one as -m_n OC_n a_v sin(phi_n) -> 0 (parametric only: no linear effect, so no linear
controller can use it). Dry friction has no linearisation and is left out (a disturbance).

Modal amplitudes: with the mode shapes Phi (columns, largest component +1), q = Phi^-1 phi and
q' = Phi^-1 omega; the amplitude of mode i is sqrt(q_i^2 + (q_i' / w_i)^2), in rad of the
pendulum that moves most in that mode (exact for a free undamped linear motion, an envelope for
a damped or mildly nonlinear one).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import expm

from pendsim_mj.engines.linearised import LinearModes, linear_modes
from pendsim_mj.errors import ParameterError
from pendsim_mj.rig.drives import NCHANNEL, Target
from pendsim_mj.rig.params import RigParams

Floats = NDArray[np.float64]


@dataclasses.dataclass(frozen=True)
class LinearRig:
    """The linearised rig (module docstring).

    Attributes:
      a: (4, 4) state matrix, 1/s and 1/s^2.
      b: (4, 4) input matrix, one column per drive channel (``Target`` order).
      modes: the normal modes (frequencies, shapes, M, C, K).
    """

    a: Floats
    b: Floats
    modes: LinearModes

    def inputs(self, channels: tuple[Target, ...]) -> Floats:
        """(4, len(channels)) the columns of B for these channels."""
        return self.b[:, [t.index for t in channels]]

    def discrete(self, dt_s: float, channels: tuple[Target, ...]) -> tuple[Floats, Floats]:
        """(Ad, Bd): x[k+1] = Ad x[k] + Bd u[k] with u held over the period dt_s (exact, by the
        matrix exponential of [[A, B], [0, 0]] dt)."""
        if not (math.isfinite(dt_s) and dt_s > 0):
            raise ParameterError(f"the control period must be > 0 s, got {dt_s!r}")
        b = self.inputs(channels)
        m = b.shape[1]
        block = np.zeros((4 + m, 4 + m))
        block[:4, :4], block[:4, 4:] = self.a, b
        e = expm(block * dt_s)
        return e[:4, :4], e[:4, 4:]

    @property
    def energy_weight(self) -> Floats:
        """(4, 4) W with x' W x / 2 = the linearised mechanical energy (K for the angles, M for
        the rates), J."""
        w = np.zeros((4, 4))
        w[:2, :2] = self.modes.stiffness_n_m
        w[2:, 2:] = self.modes.mass_kg_m2
        return w

    def mode_amplitudes_rad(self, states: Floats) -> Floats:
        """(..., 2) the amplitude of each normal mode (module docstring) of states (..., 4)."""
        x = np.asarray(states, dtype=float)
        inv = np.linalg.inv(self.modes.shapes)
        q = x[..., :2] @ inv.T
        qdot = x[..., 2:] @ inv.T
        amplitude: Floats = np.sqrt(q * q + (qdot / self.modes.omega_rad_s) ** 2)
        return amplitude

    def decay_rates_1_s(self, a: Floats | None = None) -> Floats:
        """(2,) decay rates of the two oscillatory modes of A (or of a closed loop's matrix): minus
        the real parts of its eigenvalues, slowest first, 1/s."""
        ev = np.linalg.eigvals(self.a if a is None else a)
        rates = np.sort(-ev.real[ev.imag >= 0]) if np.sum(ev.imag > 0) == 2 else np.sort(-ev.real)[:2]
        return rates[:2]


def linearise(params: RigParams) -> LinearRig:
    """The rig linearised about rest (module docstring)."""
    modes = linear_modes(params)
    m_inv = np.diag(1.0 / np.diag(modes.mass_kg_m2))
    a = np.zeros((4, 4))
    a[:2, 2:] = np.eye(2)
    a[2:, :2] = -m_inv @ modes.stiffness_n_m
    a[2:, 2:] = -m_inv @ modes.damping_n_m_s
    moments = np.zeros((2, NCHANNEL))
    moments[0, Target.TORQUE_M1.index] = 1.0
    moments[1, Target.TORQUE_M2.index] = 1.0
    moments[:, Target.SUPPORT_X.index] = [-params.m1_kg * params.oc1_m, -params.m2_kg * params.oc2_m]
    b = np.zeros((4, NCHANNEL))
    b[2:] = m_inv @ moments
    return LinearRig(a=a, b=b, modes=modes)


def decay_time_s(t_s: Floats, amplitude: Floats, fraction: float = 1.0 / math.e) -> float:
    """The time after which an envelope ``amplitude`` (n,) stays below ``fraction`` of its first
    value, s (the end of the last sample above it; linear interpolation at the crossing); inf
    where it never falls below it within the run."""
    t = np.asarray(t_s, dtype=float)
    a = np.asarray(amplitude, dtype=float)
    level = fraction * a[0]
    above = np.flatnonzero(a >= level)
    if not len(above):
        return 0.0
    k = int(above[-1])
    if k == len(a) - 1:
        return math.inf
    a0, a1 = a[k], a[k + 1]
    return float(t[k] + (t[k + 1] - t[k]) * (a0 - level) / (a0 - a1))
