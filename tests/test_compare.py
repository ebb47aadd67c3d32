import numpy as np

from hil.ident import motion_phases, noise_floor, nrmse_fit, relative_error, spectrum_peaks


def test_fit_and_relative_error():
    y = np.sin(np.linspace(0, 10, 1000))
    assert nrmse_fit(y, y) == 100.0
    assert relative_error(y, 0.9 * y) == np.float64(10.0).round(6) or abs(relative_error(y, 0.9 * y) - 10.0) < 1e-9


def test_noise_floor_of_white_noise():
    rng = np.random.default_rng(0)
    r = rng.normal(0, 2e-6, 20000) + 1e-4 * np.sin(np.linspace(0, 6, 20000))
    assert abs(noise_floor(r) / 2e-6 - 1) < 0.05


def test_spectrum_peak_frequency():
    t = np.arange(3000) * 4e-3
    f, _ = spectrum_peaks(np.sin(2 * np.pi * 15.2 * t), 4e-3, n=1)[0]
    assert abs(f - 15.2) < 0.1


def test_phases_cover_moves():
    t = np.arange(1000) * 1e-3
    x = np.where(t < 0.5, 0.5 * t ** 2, 0.125 + 0.5 * (t - 0.5))
    ph = motion_phases(t, x)
    assert ph["acceleration"][100:400].mean() > 0.9
    assert ph["constant speed"][700:950].mean() > 0.9
