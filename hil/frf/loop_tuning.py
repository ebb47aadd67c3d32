"""Tuning help from measured loops: margins, bandwidths, largest gains, filters, feed-forward.

The measured open loops (``Lv``, ``Lp``) are continued above the measured band by the model's
(the margins need the whole loop); gains are only suggested with the crossover inside the
measured band, where the measurement speaks. Structural modes seen in the velocity loop get a
note: phase-stabilised (no filter), gain-stabilised (a notch, or a low-pass), or below the
crossover. Nothing here changes a configuration: the suggestions come back as a config diff text.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from hil.frf.estimation import Response
from hil.frf.model import model_responses, position_hold

__all__ = ["margins", "bandwidth", "largest_gain", "tuning", "acc_ff_effect"]


def margins(f, L) -> dict:
    """Gain margin (dB), phase margin (deg), crossover and phase-crossover frequencies (Hz) of an
    open loop L sampled at f (linear interpolation between lines; None where not in the data)."""
    f, L = np.asarray(f), np.asarray(L)
    mag = np.abs(L)
    ph = np.unwrap(np.angle(L))
    out = {"crossover_hz": None, "phase_margin_deg": None, "phase_crossover_hz": None, "gain_margin_db": None}
    # every crossing of |L| = 1: the crossover is the last one down, the phase margin the least
    idx = np.nonzero((mag[:-1] >= 1) != (mag[1:] >= 1))[0]
    pms = []
    for i in idx:
        t = (np.log(mag[i])) / (np.log(mag[i]) - np.log(mag[i + 1]))
        phc = ph[i] + t * (ph[i + 1] - ph[i])
        # the angular distance of L from -180 deg where |L| = 1
        pms.append(float(180 - abs((np.degrees(phc) + 180) % 360 - 180)))
        if mag[i] >= 1:
            out["crossover_hz"] = float(f[i] + t * (f[i + 1] - f[i]))
    if pms:
        out["phase_margin_deg"] = min(pms)
    cross = np.nonzero(np.diff(np.floor((ph + np.pi) / (2 * np.pi))) != 0)[0]
    if cross.size:
        # the margin for a gain increase: where the phase falls through -180 deg as the
        # frequency rises (a rise through it, e.g. an integrating plant under a PI at low
        # frequency, bounds a gain decrease instead); |L| >= 1 there gives a negative margin
        gms = []
        for i in cross:
            m = 0.5 * (mag[i] + mag[i + 1])
            if ph[i + 1] < ph[i]:
                gms.append((-20 * np.log10(m), f[i]))
        if gms:
            gm, fg = min(gms)
            out["gain_margin_db"], out["phase_crossover_hz"] = float(gm), float(fg)
    return out


def bandwidth(f, T) -> float | None:
    """-3 dB bandwidth of a closed loop (first frequency where |T| < 1/sqrt 2)."""
    idx = np.nonzero(np.abs(T) < 1 / math.sqrt(2))[0]
    return float(f[idx[0]]) if idx.size else None


def largest_gain(f, L, pm_min: float, gm_min_db: float, f_trust: float = math.inf) -> tuple[float, dict]:
    """Largest factor a on the loop gain (a L) keeping the phase margin >= pm_min and the gain
    margin >= gm_min_db, with the crossover below ``f_trust`` (the measured band's top: above it
    only the model speaks). Returns (a, margins at a)."""
    best = (None, None)
    for a in np.logspace(-1.5, 1.5, 241):
        m = margins(f, a * L)
        ok = (m["phase_margin_deg"] is None or m["phase_margin_deg"] >= pm_min) and \
             (m["gain_margin_db"] is None or m["gain_margin_db"] >= gm_min_db) and m["crossover_hz"] is not None \
             and m["crossover_hz"] <= f_trust
        if ok:
            best = (float(a), m)
    return best


def _extended(r, model_wide, name, f_max):
    """A measured response continued above its band by the model's (the margins need the whole
    loop; the measurement only covers the band)."""
    if r is None:
        return None
    if not model_wide or name not in model_wide:
        return r
    fw, hw = model_wide["f"], model_wide[name]
    sel = (fw > r.f[-1]) & (fw < f_max)
    return Response(np.concatenate([r.f, fw[sel]]), np.concatenate([r.h, hw[sel]]),
                    np.concatenate([r.coherence, np.ones(sel.sum())]), np.concatenate([r.sigma, np.zeros(sel.sum())]),
                    derived=r.derived)


def tuning(responses: dict, ctrl, modes: list[dict], pm_min: float = 45.0, gm_min_db: float = 6.0,
           plant=None, model_wide: dict | None = None) -> dict:
    """Margins, bandwidths, largest gains keeping the margins, filter suggestions for structural
    modes in the velocity loop, the acceleration feed-forward's effect; the config diff as text.
    ``model_wide``: the model's responses above the measured band ({"f": ..., "Lv": ..., "Lp": ...}),
    joined to the measured loops for the margins."""
    out = {}
    diff = []
    lv = _extended(responses.get("Lv"), model_wide, "Lv", 0.5 / ctrl.velocity_period)
    lp = _extended(responses.get("Lp"), model_wide, "Lp", 0.5 / ctrl.position_period)
    if lv is not None:
        out["velocity_loop"] = dict(margins(lv.f, lv.h), bandwidth_hz=bandwidth(lv.f, lv.h / (1 + lv.h)))
        f_trust = responses["Lv"].f[-1]
        a, m = largest_gain(lv.f, lv.h, pm_min, gm_min_db, f_trust)
        if a is not None:
            out["velocity_loop"]["kp_max"] = ctrl.kp * a
            out["velocity_loop"]["at_kp_max"] = m
            diff.append(f'control.kp = "{ctrl.kp * a:.4g} N*m*s/rad"   # was {ctrl.kp:.4g}: largest Kp keeping '
                        f'PM >= {pm_min:g} deg, GM >= {gm_min_db:g} dB with the crossover ({m["crossover_hz"]:.1f} Hz) '
                        f'inside the measured band')
    if lp is not None:
        out["position_loop"] = dict(margins(lp.f, lp.h))
        # the feedback's bandwidth (the feed-forward makes x/x_cmd flat far beyond it)
        out["position_loop"]["bandwidth_hz"] = bandwidth(lp.f, lp.h / (1 + lp.h))
        a, m = largest_gain(lp.f, lp.h, pm_min, gm_min_db, responses["Lp"].f[-1])
        if a is not None:
            out["position_loop"]["kv_max"] = ctrl.kv * a
            out["position_loop"]["at_kv_max"] = m
            diff.append(f'control.kv = "{ctrl.kv * a:.4g} 1/s"   # was {ctrl.kv:.4g}: largest Kv keeping '
                        f'PM >= {pm_min:g} deg, GM >= {gm_min_db:g} dB (with the present Kp)')
    # structural modes in the velocity loop: peak of |Lv| near each fitted mode
    filters = []
    if lv is not None:
        fc = out["velocity_loop"].get("crossover_hz") or 0.0
        for row in modes:
            fm, zm = row["measured"]["frequency_hz"], row["measured"]["damping_ratio"]
            near = np.abs(lv.f - fm) < max(3 * zm * fm, 2 * (lv.f[1] - lv.f[0]))
            if not near.any():
                continue
            ipk = np.argmax(np.abs(lv.h) * near)
            peak_db = float(20 * np.log10(np.abs(lv.h[ipk])))
            ph_pk = float(np.degrees(np.angle(lv.h[ipk])))
            # phase distance from -180 deg at the peak: a collocated mode (phase near 0) is
            # phase-stabilised, a mode near -180 deg must be gain-stabilised
            dist = 180 - abs(ph_pk)
            if fm > fc and peak_db > -gm_min_db and dist > 90:
                filters.append({"mode_hz": fm, "loop_gain_db": peak_db, "phase_deg": ph_pk,
                                "note": "phase-stabilised (loop phase far from -180 deg at the mode): no filter "
                                        "needed at the present gains; a notch would cost phase margin"})
                diff.append(f"# velocity loop: |Lv| = {peak_db:+.1f} dB at the {fm:.1f} Hz mode, phase {ph_pk:.0f} deg: "
                            f"phase-stabilised, no filter needed now (a notch at {fm:.1f} Hz if delays grow)")
            elif fm > fc and peak_db > -gm_min_db:
                depth = peak_db + gm_min_db + 6
                width = max(2 * zm * fm * 2, 0.1 * fm)
                filters.append({"mode_hz": fm, "loop_gain_db": peak_db, "notch_hz": fm, "notch_width_hz": width,
                                "notch_depth_db": depth, "lowpass_hz": fm / 3 if fm / 3 > 2 * fc else None})
                diff.append(f"# velocity loop: |Lv| = {peak_db:+.1f} dB at the {fm:.1f} Hz mode (above crossover "
                            f"{fc:.1f} Hz): a notch at {fm:.1f} Hz, width {width:.1f} Hz, depth {depth:.0f} dB"
                            + (f", or a low-pass at {fm / 3:.0f} Hz" if fm / 3 > 2 * fc else "")
                            + f'; in the config: [[control.filters]] kind = "notch", frequency = "{fm:.1f}Hz", '
                              f'width = "{width:.1f}Hz", depth = "-{depth:.0f}dB"')
            elif fm < fc and peak_db < 20:
                filters.append({"mode_hz": fm, "loop_gain_db": peak_db, "note": "below the crossover: the loop "
                                "acts on it; a notch would cost phase margin"})
    out["filters"] = filters
    if plant is not None:
        out["acceleration_feed_forward"] = acc_ff_effect(plant, ctrl)
        e = out["acceleration_feed_forward"]
        if e["error_per_acc_with_ff"] < e["error_per_acc_now"] * 0.5:
            diff.append(f"control.acc_ff = 1.0   # was {e['acc_ff_now']:g}: following error per acceleration "
                        f"{e['error_per_acc_now'] * 1e6:.3g} -> {e['error_per_acc_with_ff'] * 1e6:.3g} um/(m/s^2)")
    out["config_diff"] = "\n".join(diff)
    return out


def acc_ff_effect(plant, ctrl, f_low: float = 0.5) -> dict:
    """Low-frequency following error per commanded acceleration (m per m/s^2) of the table, with the
    present acceleration feed-forward and with a full one (acc_ff = 1: the total inertia)."""
    tp = ctrl.position_period
    f = np.array([f_low])
    res = {}
    frac_now = ctrl.acc_ff * plant.force_gain / plant.total_mass
    for label, aff in (("now", ctrl.acc_ff), ("with_ff", plant.total_mass / plant.force_gain)):
        c = replace(ctrl, acc_ff=aff)
        m = model_responses(plant, replace(c, acc_ff=0.0), f, tip_measured=False)
        Lv = m["Lv"]
        # x_table / x_cmd with the feed-forward: P (speed ref -> table) and the torque path
        Gw = m["TF1p"]
        C = Lv / Gw
        hold = position_hold(f, tp)
        scale = c.speed_scale
        disc_P = m["Lp"] / (c.kv * scale * hold)          # x_table per speed reference
        gx2 = disc_P * (1 + Lv) / C                       # x_table per torque
        s = 2j * np.pi * f
        ff = c.ffv * (np.exp(s * tp) - 1) / tp
        x_over_cmd = (scale * (c.kv + ff) * hold * disc_P + aff * s ** 2 * hold * gx2 / (1 + Lv)) / (1 + m["Lp"])
        e = np.abs(1 - x_over_cmd) / np.abs(s) ** 2
        res[f"error_per_acc_{label}"] = float(e[0])
    res["acc_ff_now"] = frac_now
    return res

