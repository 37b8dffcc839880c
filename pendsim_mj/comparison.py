"""Planar against spatial: how much the third dimension matters (issue 7).

Both variants run from the same release. Per pendulum: the in-plane angle difference over time;
the out-of-plane (tilt) amplitude about its mean; the beat of the swing, read from the envelope of
phi (magnitude of the analytic signal, scipy.signal.hilbert, averaged over one carrier period)
with its damping decay divided out: the period is the envelope's spectral peak below a third of
the carrier frequency (faster "modulation" is several modes mixing, visible in the spectrum), the
depth is (high - low) / (high + low) of the 2nd and 98th percentiles of the envelope about its
running geometric mean over one beat period; and the spectrum of phi near the main frequency.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.signal import find_peaks, hilbert

from pendsim_mj.analysis import hann_magnitude, padded_length, spectral_peak_hz
from pendsim_mj.drives import Drive
from pendsim_mj.model import PLANAR, SPATIAL, Variant
from pendsim_mj.params import RigParams
from pendsim_mj.simulation import simulate
from pendsim_mj.trajectory import Trajectory


@dataclasses.dataclass(frozen=True)
class Beat:
    """Envelope modulation of one swing: period (s; inf if the depth is under 1 %) and depth (0-1)."""

    period_s: float
    depth: float


def envelope(t_s: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The swing's amplitude over time: |analytic signal| of x - mean(x)."""
    return np.abs(hilbert(x - x.mean()))


def beat(t_s: np.ndarray, x: np.ndarray, *, edge_s: float = 5.0) -> Beat:
    """Period and depth of the envelope's modulation, the damping decay divided out (a straight
    line fitted to log envelope), ignoring ``edge_s`` at both ends (Hilbert edge effects)."""
    env = envelope(t_s, x)
    # the Hilbert envelope ripples at the carrier frequency and its double: average over a period
    dt = (t_s[-1] - t_s[0]) / (len(t_s) - 1)
    carrier_hz = spectral_peak_hz(t_s, x)
    window = round(1.0 / (carrier_hz * dt)) if carrier_hz > 0 else 1  # ripple at f and 2 f
    if 1 < window < len(env) // 4:
        env = np.convolve(env, np.ones(window) / window, mode="same")
    inner = (t_s >= t_s[0] + edge_s) & (t_s <= t_s[-1] - edge_s)
    t, e = t_s[inner], env[inner]
    if len(t) < 16 or np.any(e <= 0):
        return Beat(math.inf, 0.0)
    flat = e / np.exp(np.polyval(np.polyfit(t, np.log(e), 1), t))  # the damping decay divided out
    # a beat is an envelope modulation slower than a third of the carrier frequency (faster
    # "modulation" is several modes mixing: see the spectrum)
    f = spectral_peak_hz(t, flat, max_hz=carrier_hz / 3)
    if f <= 0:
        return Beat(math.inf, 0.0)
    # depth: peak to peak of the envelope about its running geometric mean over one beat period
    # (exact for a periodic modulation of a decaying swing), 2nd-98th percentiles
    window = round(1.0 / (f * dt))
    if not 2 < window < len(e) // 2:
        return Beat(math.inf, 0.0)
    log_e = np.log(e)
    trend = np.convolve(log_e, np.ones(window) / window, mode="valid")
    ratio = np.exp(log_e[window // 2 : window // 2 + len(trend)] - trend)
    low, high = np.percentile(ratio, [2, 98])
    depth = float((high - low) / (high + low))
    if depth < 0.01:  # under 1 %: ripple of the nonlinear swing, not a beat
        return Beat(math.inf, depth)
    return Beat(1.0 / f, depth)


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
class Comparison3D:
    planar: Trajectory
    spatial: Trajectory
    summary: dict


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
        pendulums[name] = {
            "in_plane_difference_max_rad": float(np.max(np.abs(diff))),
            "in_plane_difference_rms_rad": float(np.sqrt(np.mean(diff * diff))),
            "first_time_difference_exceeds_1_deg_s": _first_time(t, np.abs(diff) > math.radians(1)),
            "out_of_plane_mean_rad": float(tilt.mean()),
            "out_of_plane_amplitude_rad": float(np.max(np.abs(tilt - tilt.mean()))),
            "beat_period_s": {v: _finite(b.period_s) for v, b in beats.items()},
            "beat_depth": {v: b.depth for v, b in beats.items()},
            "spectrum_peaks_hz": {v: p for v, p in peaks.items()},
        }
    summary = {
        "release_rad": list(phi0_rad),
        "duration_s": duration_s,
        "dt_s": dt_s,
        "plane_offset_m": params.plane_offset_m,
        "tilt_stiffness_n_m_rad": params.tilt_stiffness_n_m_rad,
        "tilt_damping_n_m_s_rad": params.tilt_damping_n_m_s_rad,
        "fixed_points_plane": variant.fixed_points_plane,
        "main_frequency_hz": main_hz,
        "pendulums": pendulums,
    }
    return Comparison3D(planar, spatial, summary)


def _first_time(t: np.ndarray, mask: np.ndarray) -> float | None:
    hit = np.flatnonzero(mask)
    return float(t[hit[0]]) if len(hit) else None


def _finite(v: float) -> float | None:
    return v if math.isfinite(v) else None
