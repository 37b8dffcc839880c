"""The rig linearised about rest, from the planar reference's equations (no MuJoCo).

M q'' + C q' + (K_s + G) q = 0 with q = (phi1, phi2): M = diag(J1, J2) (two hinges on one
fixed axis: no inertial coupling), C = diag(b1, b2), G = diag(m1 g OC1, m2 g OC2) the gravity
stiffness and K_s = -d(M1, M2)/d(phi1, phi2) the springs' stiffness at rest, by central
differences of ``reference.spring_moments``. The normal modes are the solutions of
(K_s + G) u = w^2 M u, each shape scaled to a largest component of +1.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from pendsim_mj.engines import reference
from pendsim_mj.rig.params import RigParams


@dataclasses.dataclass(frozen=True)
class LinearModes:
    """The linearised rig at rest.

    Attributes:
      mass_kg_m2: (2, 2) M. damping_n_m_s: (2, 2) C. spring_stiffness_n_m: (2, 2) K_s.
      gravity_stiffness_n_m: (2, 2) G. omega_rad_s: (2,) undamped natural angular frequencies,
      ascending. shapes: (2, 2) mode shapes as columns, largest component +1.
      gravity_m_s2: g.
    """

    mass_kg_m2: NDArray[np.float64]
    damping_n_m_s: NDArray[np.float64]
    spring_stiffness_n_m: NDArray[np.float64]
    gravity_stiffness_n_m: NDArray[np.float64]
    omega_rad_s: NDArray[np.float64]
    shapes: NDArray[np.float64]
    gravity_m_s2: float

    @property
    def frequency_hz(self) -> NDArray[np.float64]:
        return self.omega_rad_s / (2 * math.pi)

    @property
    def stiffness_n_m(self) -> NDArray[np.float64]:
        return self.spring_stiffness_n_m + self.gravity_stiffness_n_m

    def modal(self, matrix: NDArray[np.float64]) -> NDArray[np.float64]:
        """Phi^T A Phi with the mass-normalised shapes Phi (Phi^T M Phi = I)."""
        phi = self.shapes / np.sqrt(np.einsum("im,ij,jm->m", self.shapes, self.mass_kg_m2, self.shapes))
        return phi.T @ matrix @ phi


def linear_modes(params: RigParams, *, eps_rad: float = 1e-6) -> LinearModes:
    """Linearise the reference's equations at rest (module docstring)."""
    k = reference._coefficients([params])
    stiffness = np.zeros((2, 2))
    for j in range(2):
        plus, minus = np.zeros((2, 1)), np.zeros((2, 1))
        plus[j], minus[j] = eps_rad, -eps_rad
        mp = np.array(reference.spring_moments(plus[0], plus[1], k)[:2])[:, 0]
        mm = np.array(reference.spring_moments(minus[0], minus[1], k)[:2])[:, 0]
        stiffness[:, j] = -(mp - mm) / (2 * eps_rad)
    stiffness = 0.5 * (stiffness + stiffness.T)  # conservative springs: symmetric up to rounding
    mass = np.diag([params.j1_kg_m2, params.j2_kg_m2])
    gravity = np.diag([params.m1_kg * params.g_m_s2 * params.oc1_m, params.m2_kg * params.g_m_s2 * params.oc2_m])
    # generalised symmetric problem via M^-1/2 (K) M^-1/2
    m_half = np.diag(1 / np.sqrt(np.diag(mass)))
    w2, v = np.linalg.eigh(m_half @ (stiffness + gravity) @ m_half)
    shapes = m_half @ v
    shapes = shapes / shapes[np.argmax(np.abs(shapes), axis=0), [0, 1]]
    return LinearModes(
        mass_kg_m2=mass,
        damping_n_m_s=np.diag([params.b1_n_m_s, params.b2_n_m_s]),
        spring_stiffness_n_m=stiffness,
        gravity_stiffness_n_m=gravity,
        omega_rad_s=np.sqrt(w2),
        shapes=shapes,
        gravity_m_s2=params.g_m_s2,
    )
