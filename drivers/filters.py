"""Second-order filter sections of the velocity loop (notch, low-pass, general biquad), designed once
and run in the one control law (drivers.control) on the torque setpoint or on the speed feedback.

A section is its discrete coefficients ``(b0, b1, b2, a1, a2)`` at the velocity period ``Tv``
(``a0 = 1``): ``y = b0 x + z1; z1 = b1 x - a1 y + z2; z2 = b2 x - a2 y`` (the transposed direct
form II, two states). The continuous notch and low-pass are discretized by the bilinear transform
pre-warped at their frequency (scipy.signal.bilinear), so that the discrete section has its notch,
or its corner, exactly where it was asked:

* ``notch``: ``H(s) = (s^2 + 2 d zeta w s + w^2) / (s^2 + 2 zeta w s + w^2)`` with ``zeta = width
  / (2 f)`` (the width, Hz, between the -3 dB points of a deep notch) and ``d`` the depth as a gain
  (``depth = "-20dB"``: 0.1; ``|H(j w)| = d``);
* ``lowpass``: ``H(s) = w^2 / (s^2 + 2 zeta w s + w^2)``, ``zeta`` the damping ratio (0.707 by
  default: Butterworth);
* ``biquad``: the discrete coefficients as given (``b = [b0, b1, b2]``, ``a = [1, a1, a2]``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["FilterSpec", "design", "sections", "frequency_response", "MAX_SECTIONS", "KINDS", "PLACES"]

MAX_SECTIONS = 4          # sections at each place (torque setpoint, speed feedback)
KINDS = ("notch", "lowpass", "biquad")
PLACES = ("torque", "speed")


@dataclass(frozen=True)
class FilterSpec:
    """One filter as configured (SI): ``kind``, ``at`` (``torque``: the velocity controller's output,
    ``speed``: the speed feedback), ``frequency`` (Hz), ``width`` (Hz, notch), ``depth`` (gain at the
    notch, linear), ``damping`` (low-pass), ``b``/``a`` (biquad)."""
    kind: str
    at: str = "torque"
    frequency: float = 0.0
    width: float = 0.0
    depth: float = 0.0
    damping: float = math.sqrt(0.5)
    b: tuple = ()
    a: tuple = ()


def design(spec: FilterSpec, tv: float) -> tuple[float, float, float, float, float]:
    """The section ``(b0, b1, b2, a1, a2)`` of ``spec`` at the velocity period ``tv`` (not real-time)."""
    if spec.kind == "biquad":
        b, a = np.asarray(spec.b, float), np.asarray(spec.a, float)
        b, a = b / a[0], a / a[0]
        return float(b[0]), float(b[1]), float(b[2]), float(a[1]), float(a[2])
    from scipy.signal import bilinear
    fs = 1.0 / tv
    if not 0.0 < spec.frequency < 0.5 * fs:
        raise ValueError(f"{spec.kind} at {spec.frequency:g} Hz: expected a frequency between 0 and the velocity "
                         f"loop's Nyquist frequency {0.5 * fs:g} Hz")
    # pre-warped: the analogue filter at w_a maps to exactly w after the bilinear transform
    w = 2.0 * math.pi * spec.frequency
    wa = 2.0 * fs * math.tan(w / (2.0 * fs))
    if spec.kind == "notch":
        zeta = spec.width / (2.0 * spec.frequency)
        num, den = [1.0, 2.0 * spec.depth * zeta * wa, wa * wa], [1.0, 2.0 * zeta * wa, wa * wa]
    elif spec.kind == "lowpass":
        num, den = [wa * wa], [1.0, 2.0 * spec.damping * wa, wa * wa]
    else:
        raise ValueError(f"filter kind {spec.kind!r}: one of {', '.join(KINDS)}")
    bz, az = bilinear(num, den, fs)
    bz = np.pad(bz, (3 - bz.size, 0))
    return float(bz[0]), float(bz[1]), float(bz[2]), float(az[1]), float(az[2])


def sections(specs, tv: float, at: str) -> tuple:
    """The designed sections of ``specs`` placed ``at`` (``torque`` or ``speed``), in order."""
    out = tuple(design(s, tv) for s in specs if s.at == at)
    if len(out) > MAX_SECTIONS:
        raise ValueError(f"control.filters: at most {MAX_SECTIONS} on the {at} path, got {len(out)}")
    return out


def frequency_response(secs, f, tv: float) -> np.ndarray:
    """The cascade of ``secs`` at the frequencies ``f`` (Hz): ``prod_i B_i(z) / A_i(z)``, z = exp(j 2 pi
    f tv) (the closed form the tests and the lifted loop compare with)."""
    z = np.exp(-2j * np.pi * np.asarray(f, float) * tv)
    h = np.ones_like(z)
    for b0, b1, b2, a1, a2 in secs:
        h = h * (b0 + b1 * z + b2 * z * z) / (1.0 + a1 * z + a2 * z * z)
    return h
