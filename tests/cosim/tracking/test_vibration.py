"""Vibration metrics of cosim.tracking.metrics on synthetic signals with known answers."""
import math

import numpy as np

from cosim.tracking.metrics import dominant_peak, error_spectrum, evaluate, residual_vibration


def test_residual_vibration_of_a_damped_oscillation_about_a_static_offset():
    t = np.arange(0.0, 1.0, 1e-3)
    t_end, f, zeta_w, a0 = 0.2, 12.0, 12.0, 0.5e-3  # 0.5 mm, decays with exp(-12 t)
    offset = np.array([30e-6, -40e-6, 0.0])  # 50 um static offset
    ring = a0 * np.exp(-zeta_w * np.clip(t - t_end, 0, None)) * np.cos(2 * np.pi * f * (t - t_end))
    error = offset + np.column_stack([ring, np.zeros_like(t), np.zeros_like(t)])
    out = residual_vibration(t, error, t_end, band=20e-6)
    assert math.isclose(out["static_offset_mm"], 0.05, rel_tol=1e-3)
    assert math.isclose(out["peak_mm"], 0.5, rel_tol=1e-4)  # about the averaged final pose
    expected = math.log(a0 / 20e-6) / zeta_w  # envelope reaches the band; the last crossing is within a period
    assert expected - 1 / f <= out["settling_time_s"] <= expected + 1e-3
    assert math.isclose(out["window_s"], t[-1] - t_end, rel_tol=1e-9)
    still = residual_vibration(t, np.column_stack([a0 * np.cos(2 * np.pi * f * t), 0 * t, 0 * t]), t_end, 20e-6)
    assert math.isnan(still["settling_time_s"])  # never settles within the recording
    rest = residual_vibration(t, np.tile(offset, (t.size, 1)), t_end, 20e-6)
    assert rest["settling_time_s"] == 0.0 and rest["peak_mm"] < 1e-12


def test_spectrum_finds_the_vibration_line_and_its_amplitude():
    t = np.arange(0.0, 4.0, 1e-3)
    error = np.column_stack([0.2e-3 * np.sin(2 * np.pi * 11.0 * t), 0.1e-3 * np.cos(2 * np.pi * 11.0 * t),
                             1e-3 * t])  # a slow drift below SPECTRUM_MIN_HZ is not the peak
    freq, amplitude = error_spectrum(t, error)
    f_peak, a_peak = dominant_peak(freq, amplitude)
    assert abs(f_peak - 11.0) < 0.26
    assert math.isclose(a_peak, math.hypot(0.2e-3, 0.1e-3), rel_tol=0.02)


def test_evaluate_reports_vibration_fields():
    t = np.arange(0.0, 1.0, 1e-3)
    zeros = np.zeros((t.size, 3))
    actual = zeros.copy()
    actual[:, 0] = 1e-4 * np.sin(2 * np.pi * 15 * t)
    res = evaluate(t, np.zeros((t.size, 6)), actual, np.zeros((t.size, 6)), zeros, zeros, np.zeros(t.size, int),
                   (0.0, 0.8), actual=actual)
    m = res.metrics()
    assert abs(m["tcp_error_spectrum_peak_hz"] - 15) < 1.5
    assert set(m["residual_vibration"]) == {"peak_mm", "settling_time_s", "static_offset_mm", "band_mm", "window_s"}
    assert res.residual_t.size == 200 and res.residual_error.max() > 0
