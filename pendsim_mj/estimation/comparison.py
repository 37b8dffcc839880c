"""Planar against spatial: how much the third dimension matters (issue 7).

Both variants run from the same release. Per pendulum: the in-plane angle difference over time;
the out-of-plane (tilt) amplitude about its mean; the beat of the swing, measured on its carrier
band (``pendsim_mj.estimation.analysis.beat``: the envelope of phi band-passed around its dominant
frequency, so that other normal modes mixing in cannot pass for a beat); and the spectrum of phi
near the main frequency.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.signal import find_peaks

from pendsim_mj.engines.simulation import simulate
from pendsim_mj.engines.trajectory import Trajectory
from pendsim_mj.estimation.analysis import Beat, beat, carrier_envelope, hann_magnitude, padded_length, spectral_peak_hz
from pendsim_mj.rig.drives import Drive
from pendsim_mj.rig.model import PLANAR, SPATIAL, Variant
from pendsim_mj.rig.params import RigParams

__all__ = [
    "Beat",
    "Comparison3D",
    "PendulumDifference",
    "beat",
    "carrier_envelope",
    "compare_planar_spatial",
    "spectrum_near",
]


def spectrum_near(t_s: np.ndarray, x: np.ndarray, centre_hz: float, half_width_hz: float = 0.3):
    """Frequencies (Hz) and Hann-windowed magnitudes of x within centre +- half width, and the
    peaks there (frequency, relative height), highest first."""
    dt = (t_s[-1] - t_s[0]) / (len(t_s) - 1)
    nfft = padded_length(len(x))
    mag = hann_magnitude(x, nfft)
    f = np.fft.rfftfreq(nfft, dt)
    band = (f >= centre_hz - half_width_hz) & (f <= centre_hz + half_width_hz)
    fb, mb = f[band], mag[band] / mag[band].max()
    peaks, _ = find_peaks(mb, height=0.05)
    order = np.argsort(mb[peaks])[::-1]
    return fb, mb, [(float(fb[p]), float(mb[p])) for p in peaks[order][:5]]


@dataclasses.dataclass(frozen=True)
class PendulumDifference:
    """How one pendulum's swing differs between the planar and the spatial model.

    Attributes:
      in_plane_difference_max_rad, in_plane_difference_rms_rad: of phi_spatial - phi_planar.
      first_time_difference_exceeds_1_deg_s: when |difference| first exceeds 1 deg (None: never).
      out_of_plane_mean_rad, out_of_plane_amplitude_rad: the tilt's mean and largest excursion
        about it.
      beats: per model ("planar", "spatial") the beat on the carrier band.
      spectrum_peaks_hz: per model the peaks of phi near the main frequency, (Hz, relative height),
        highest first.
    """

    in_plane_difference_max_rad: float
    in_plane_difference_rms_rad: float
    first_time_difference_exceeds_1_deg_s: float | None
    out_of_plane_mean_rad: float
    out_of_plane_amplitude_rad: float
    beats: dict[str, Beat]
    spectrum_peaks_hz: dict[str, list[tuple[float, float]]]

    def to_json(self) -> dict[str, object]:
        """The JSON form written to summary.json (beats as period, depth and carrier per model)."""
        return {
            "in_plane_difference_max_rad": self.in_plane_difference_max_rad,
            "in_plane_difference_rms_rad": self.in_plane_difference_rms_rad,
            "first_time_difference_exceeds_1_deg_s": self.first_time_difference_exceeds_1_deg_s,
            "out_of_plane_mean_rad": self.out_of_plane_mean_rad,
            "out_of_plane_amplitude_rad": self.out_of_plane_amplitude_rad,
            "beat_period_s": {v: _finite(b.period_s) for v, b in self.beats.items()},
            "beat_depth": {v: b.depth for v, b in self.beats.items()},
            "beat_carrier_hz": {v: b.carrier_hz for v, b in self.beats.items()},
            "spectrum_peaks_hz": dict(self.spectrum_peaks_hz),
        }


@dataclasses.dataclass(frozen=True)
class Comparison3D:
    """Planar against spatial from one release.

    Attributes:
      planar, spatial: the two runs.
      release_rad: (phi1, phi2) at the release; duration_s, dt_s: the runs' span and step.
      plane_offset_m, tilt_stiffness_n_m_rad, tilt_damping_n_m_s_rad: the spatial rig's.
      fixed_points_plane: the plane of the frame's spring points ("m1" or "m2").
      main_frequency_hz: the planar phi1's dominant frequency.
      pendulums: per pendulum ("m1", "m2") its differences.
    """

    planar: Trajectory
    spatial: Trajectory
    release_rad: tuple[float, float]
    duration_s: float
    dt_s: float
    plane_offset_m: float
    tilt_stiffness_n_m_rad: float
    tilt_damping_n_m_s_rad: float
    fixed_points_plane: str
    main_frequency_hz: float
    pendulums: dict[str, PendulumDifference]

    def to_json(self) -> dict[str, object]:
        """summary.json: every field but the two runs."""
        return {
            "release_rad": list(self.release_rad),
            "duration_s": self.duration_s,
            "dt_s": self.dt_s,
            "plane_offset_m": self.plane_offset_m,
            "tilt_stiffness_n_m_rad": self.tilt_stiffness_n_m_rad,
            "tilt_damping_n_m_s_rad": self.tilt_damping_n_m_s_rad,
            "fixed_points_plane": self.fixed_points_plane,
            "main_frequency_hz": self.main_frequency_hz,
            "pendulums": {name: p.to_json() for name, p in self.pendulums.items()},
        }


def compare_planar_spatial(
    params: RigParams,
    phi0_rad: tuple[float, float],
    duration_s: float = 120.0,
    dt_s: float = 0.01,
    *,
    variant: Variant = SPATIAL,
    drive: Drive | None = None,
) -> Comparison3D:
    """Run the planar model and the spatial variant (params.plane_offset_m, tilt freedoms) from
    the same release, both under ``drive`` if given, and summarise the differences (see the
    module docstring)."""
    planar_params = params.with_overrides(plane_offset_m=0.0)
    planar = simulate(planar_params, phi0_rad, (0.0, 0.0), duration_s, dt_s, variant=PLANAR, drive=drive)
    spatial = simulate(params, phi0_rad, (0.0, 0.0), duration_s, dt_s, variant=variant, drive=drive)
    t = planar.t_s
    main_hz = spectral_peak_hz(t, planar.phi_rad[:, 0])
    pendulums = {}
    for k, name in enumerate(("m1", "m2")):
        diff = spatial.phi_rad[:, k] - planar.phi_rad[:, k]
        tilt = spatial.tilt_rad[:, k]
        beats = {v: beat(t, tr.phi_rad[:, k]) for v, tr in (("planar", planar), ("spatial", spatial))}
        peaks = {
            v: spectrum_near(t, tr.phi_rad[:, k], main_hz)[2] for v, tr in (("planar", planar), ("spatial", spatial))
        }
        pendulums[name] = PendulumDifference(
            in_plane_difference_max_rad=float(np.max(np.abs(diff))),
            in_plane_difference_rms_rad=float(np.sqrt(np.mean(diff * diff))),
            first_time_difference_exceeds_1_deg_s=_first_time(t, np.abs(diff) > math.radians(1)),
            out_of_plane_mean_rad=float(tilt.mean()),
            out_of_plane_amplitude_rad=float(np.max(np.abs(tilt - tilt.mean()))),
            beats=beats,
            spectrum_peaks_hz=peaks,
        )
    return Comparison3D(
        planar=planar,
        spatial=spatial,
        release_rad=(float(phi0_rad[0]), float(phi0_rad[1])),
        duration_s=duration_s,
        dt_s=dt_s,
        plane_offset_m=params.plane_offset_m,
        tilt_stiffness_n_m_rad=params.tilt_stiffness_n_m_rad,
        tilt_damping_n_m_s_rad=params.tilt_damping_n_m_s_rad,
        fixed_points_plane=variant.fixed_points_plane,
        main_frequency_hz=main_hz,
        pendulums=pendulums,
    )


def _first_time(t: np.ndarray, mask: np.ndarray) -> float | None:
    hit = np.flatnonzero(mask)
    return float(t[hit[0]]) if len(hit) else None


def _finite(v: float) -> float | None:
    return v if math.isfinite(v) else None
