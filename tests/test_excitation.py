"""Excitation generators, experiment files and measurement realism against independent references.

References: finite differences of the position (derivatives), closed-form properties (quintic boundary values
and peak velocity 15/8 D/T, Fourier periodicity and DFT lines, maximum-length-sequence balance and two-valued
autocorrelation, sample-statistics bounds), zero crossings (sweep frequency) and numerical integration
(bang-bang profiles).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from motiontwin.harness import excitation as ex
from motiontwin.harness import experiment as xp
from motiontwin.harness import measurement as ms

EXPERIMENTS = Path(__file__).resolve().parents[1] / "harness" / "experiments"


def central_derivative(f, t: np.ndarray, h: float, order: int) -> np.ndarray:
    """Fourth-order accurate central finite difference of f (a function of a time array) of the given order."""
    if order == 1:
        weights = {-2: 1 / 12, -1: -2 / 3, 1: 2 / 3, 2: -1 / 12}
    elif order == 2:
        weights = {-2: -1 / 12, -1: 4 / 3, 0: -5 / 2, 1: 4 / 3, 2: -1 / 12}
    else:
        weights = {-3: 1 / 8, -2: -1, -1: 13 / 8, 1: -13 / 8, 2: 1, 3: -1 / 8}
    return sum(w * f(t + k * h) for k, w in weights.items()) / h**order


# ---------------------------------------------------------------- quintic point-to-point


def test_quintic_derivatives_match_finite_differences():
    start, end, move_time, t0 = np.array([0.01, -0.02]), np.array([0.015, -0.024]), 0.07, 0.01
    t = np.linspace(t0 + 1e-3, t0 + move_time - 1e-3, 301)

    def position(tt):
        return ex.quintic_point_to_point(tt, start, end, move_time, t0).position

    profile = ex.quintic_point_to_point(t, start, end, move_time, t0)
    h = 1e-4
    scale_v = np.abs(profile.velocity).max()
    scale_a = np.abs(profile.acceleration).max()
    scale_j = np.abs(profile.jerk).max()
    assert np.abs(profile.velocity - central_derivative(position, t, h, 1)).max() < 1e-8 * scale_v
    assert np.abs(profile.acceleration - central_derivative(position, t, h, 2)).max() < 1e-5 * scale_a
    assert np.abs(profile.jerk - central_derivative(position, t, h, 3)).max() < 1e-3 * scale_j


def test_quintic_boundary_conditions_and_peak_velocity():
    distance, move_time, t0 = 0.005, 0.07, 0.01
    t = np.array([0.0, t0, t0 + move_time / 2, t0 + move_time, 0.2])
    p = ex.quintic_point_to_point(t, 0.0, distance, move_time, t0)
    np.testing.assert_allclose(p.position, [0, 0, distance / 2, distance, distance], atol=1e-15)
    np.testing.assert_allclose(p.velocity[[0, 1, 3, 4]], 0.0, atol=1e-15)
    np.testing.assert_allclose(p.acceleration[[0, 1, 3, 4]], 0.0, atol=1e-12)
    # Peak velocity of the quintic rest-to-rest move is 15/8 D/T, reached at mid-move.
    assert p.velocity[2] == pytest.approx(15 / 8 * distance / move_time, rel=1e-12)
    # Jerk at the start is 60 D/T^3 and the acceleration peak is 10/sqrt(3) D/T^2.
    dense = ex.quintic_point_to_point(np.linspace(t0, t0 + move_time, 20001), 0.0, distance, move_time, t0)
    assert dense.jerk[0] == pytest.approx(60 * distance / move_time**3, rel=1e-12)
    assert dense.acceleration.max() == pytest.approx(10 / math.sqrt(3) * distance / move_time**2, rel=1e-6)


def test_actuator_point_to_point_columns_and_shape_check():
    t = np.arange(400) * 5e-4
    p = ex.actuator_point_to_point(t, [0.0, 0.1, 0.2, 0.3], [0.005, 0.1, 0.196, 0.31], 0.07, 0.01)
    assert p.position.shape == (400, 4)
    np.testing.assert_allclose(p.position[-1], [0.005, 0.1, 0.196, 0.31], atol=1e-15)
    assert np.all(p.velocity[:, 1] == 0)
    with pytest.raises(ValueError, match="equal length"):
        ex.actuator_point_to_point(t, [0.0, 1.0], [1.0, 2.0, 3.0], 0.07)


def test_end_effector_move_maps_endpoints_through_inverse_kinematics():
    def toy_ik(pose):
        x, y, z, theta = pose
        return np.array([x + z, y - z, x * theta, y + theta])

    a, b = np.array([0.0914, 0.0914, 0.1237, -0.7854]), np.array([0.0951, 0.0969, 0.1223, -0.8])
    t = np.arange(400) * 5e-4
    p = ex.end_effector_point_to_point(t, a, b, 0.07, 0.01, inverse_kinematics=toy_ik)
    np.testing.assert_allclose(p.position[0], toy_ik(a), atol=1e-15)
    np.testing.assert_allclose(p.position[-1], toy_ik(b), atol=1e-15)
    reference = ex.quintic_point_to_point(t, toy_ik(a)[2], toy_ik(b)[2], 0.07, 0.01)
    np.testing.assert_allclose(p.jerk[:, 2], reference.jerk, rtol=1e-12, atol=1e-12)


def test_substrate_alignment_move_through_cheung_kinematics():
    """The paper's move: actuator quintics whose end points map back to the poses by the forward kinematics."""
    from motiontwin.harness import kinematics

    experiment = xp.load_experiment(EXPERIMENTS / "substrate_alignment.toml")
    signals = experiment.generate()
    d = signals["position"]
    assert d.shape == (400, 4)
    np.testing.assert_allclose(kinematics.cheung_forward(d[0]), [0.0914, 0.0914, 0.1237, -0.7854], atol=1e-12)
    np.testing.assert_allclose(kinematics.cheung_forward(d[-1]), [0.0951, 0.0969, 0.1223, -0.8], atol=1e-12)
    assert all(kinematics.cheung_in_range(row) for row in d)
    travel = d[-1] - d[0]
    mid = round((0.01 + 0.035) / experiment.sample_time)
    np.testing.assert_allclose(signals["velocity"][mid], 15 / 8 * travel / 0.07, rtol=1e-12)
    np.testing.assert_allclose(signals["velocity"][[0, -1]], 0.0, atol=1e-15)


# ---------------------------------------------------------------- Fourier trajectories


def fourier_case():
    a = np.array([[0.010, 0.002], [-0.004, 0.003], [0.003, -0.001], [0.002, 0.0], [-0.001, 0.001]])
    b = np.array([[0.002, -0.003], [0.005, 0.001], [-0.002, 0.002], [0.001, 0.0], [0.001, -0.002]])
    return 1.0, a, b, np.array([0.05, -0.02])


def test_fourier_trajectory_periodic_with_mean_q0():
    f, a, b, q0 = fourier_case()
    t = ex.periodic_time_grid(1 / f, 3, 5e-4)
    assert t.size == 3 * 2000
    p = ex.fourier_trajectory(t, f, a, b, q0)
    later = ex.fourier_trajectory(t + 1 / f, f, a, b, q0)
    for name in ("position", "velocity", "acceleration", "jerk"):
        np.testing.assert_allclose(getattr(later, name), getattr(p, name), atol=1e-12 * np.abs(getattr(p, name)).max())
    np.testing.assert_allclose(p.position[:2000].mean(axis=0), q0, atol=1e-15)


def test_fourier_derivatives_match_finite_differences():
    f, a, b, q0 = fourier_case()
    t = np.linspace(0, 1, 257)

    def position(tt):
        return ex.fourier_trajectory(tt, f, a, b, q0).position

    p = ex.fourier_trajectory(t, f, a, b, q0)
    h = 1e-4
    np.testing.assert_allclose(central_derivative(position, t, h, 1), p.velocity, atol=1e-9)
    np.testing.assert_allclose(central_derivative(position, t, h, 2), p.acceleration, atol=1e-6)
    np.testing.assert_allclose(central_derivative(position, t, h, 3), p.jerk, atol=5e-3)


def test_fourier_velocity_lines_are_a_minus_jb():
    """Bona eq. 18: qdot = sum a_l cos + b_l sin, so the DFT line at harmonic l is (a_l - j b_l) * M / 2."""
    f, a, b, q0 = fourier_case()
    n_periods = 4
    t = ex.periodic_time_grid(1 / f, n_periods, 1e-3)
    v = ex.fourier_trajectory(t, f, a[:, 0], b[:, 0], q0[0]).velocity
    spectrum = np.fft.rfft(v) * 2 / t.size
    lines = n_periods * np.arange(1, a.shape[0] + 1)
    np.testing.assert_allclose(spectrum[lines], a[:, 0] - 1j * b[:, 0], atol=1e-12)
    others = np.delete(np.arange(spectrum.size), lines)
    assert np.abs(spectrum[others]).max() < 1e-12


def test_periodic_grid_rejects_non_integer_period():
    with pytest.raises(ValueError, match="not an integer multiple"):
        ex.periodic_time_grid(1 / 3, 2, 1e-3)


# ---------------------------------------------------------------- swept sine


def zero_crossing_frequency(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies from successive upward/downward zero crossings (linear interpolation), at their midpoints."""
    index = np.flatnonzero(np.signbit(x[:-1]) != np.signbit(x[1:]))
    crossing = t[index] - x[index] * (t[index + 1] - t[index]) / (x[index + 1] - x[index])
    return 0.5 * (crossing[1:] + crossing[:-1]), 0.5 / np.diff(crossing)


@pytest.mark.parametrize("method,f_mid", [("linear", 290.0), ("logarithmic", math.sqrt(80.0 * 500.0))])
def test_swept_sine_frequency_from_zero_crossings(method, f_mid):
    t = np.arange(0, 1.2, 1e-6)
    x = ex.swept_sine(t, 80.0, 500.0, 1.0, amplitude=3.0, method=method, t0=0.1)
    inside = (t > 0.1) & (t < 1.1)
    times, freqs = zero_crossing_frequency(t[inside], x[inside])
    # Drop the first crossing pair: the sweep starts at phase zero, i.e. exactly on a crossing.
    times, freqs = times[1:], freqs[1:]
    # Extrapolate the measured frequencies to the sweep's start and end with local quadratic fits.
    start_fit = np.polyfit(times[:10] - 0.1, freqs[:10], 2)
    end_fit = np.polyfit(times[-40:] - 1.1, freqs[-40:], 2)
    assert np.polyval(start_fit, 0.0) == pytest.approx(80.0, rel=2e-3)
    assert np.polyval(end_fit, 0.0) == pytest.approx(500.0, rel=2e-3)
    analytic = ex.swept_sine_frequency(times, 80.0, 500.0, 1.0, method, t0=0.1)
    assert np.abs(freqs / analytic - 1).max() < 2e-3
    assert ex.swept_sine_frequency(0.6, 80.0, 500.0, 1.0, method, t0=0.1) == pytest.approx(f_mid)
    assert np.abs(x).max() == pytest.approx(3.0, rel=1e-4)
    assert np.all(x[t < 0.1] == 0) and np.all(x[t > 1.1] == 0)


def test_swept_sine_ramps_start_at_zero():
    t = np.arange(0, 1.0, 1e-5)
    x = ex.swept_sine(t, 80.0, 500.0, 1.0, amplitude=1.0, ramp_time=0.05)
    assert x[0] == 0.0
    assert np.abs(x[t < 0.005]).max() < 0.03  # raised cosine: envelope 0.024 at 10 % of the ramp
    assert np.abs(x[(t > 0.2) & (t < 0.8)]).max() == pytest.approx(1.0, rel=1e-3)


# ---------------------------------------------------------------- multisine and PRBS


def test_multisine_spectrum_only_at_chosen_lines():
    harmonics = np.array([1, 2, 3, 5, 8, 13, 21, 34, 55, 89])
    amplitudes = np.linspace(1.0, 0.3, harmonics.size)
    n_periods, fs = 3, 1000.0
    t = np.arange(int(n_periods * fs)) / fs
    x = ex.multisine(t, 1.0, harmonics, amplitudes)
    spectrum = np.abs(np.fft.rfft(x)) * 2 / t.size
    lines = n_periods * harmonics
    np.testing.assert_allclose(spectrum[lines], amplitudes, rtol=1e-10)
    others = np.delete(np.arange(spectrum.size), lines)
    assert spectrum[others].max() < 1e-10


def test_schroeder_phases_lower_crest_factor():
    t = np.arange(2000) / 2000
    k = 31
    crest = lambda x: np.abs(x).max() / np.sqrt(np.mean(x**2))  # noqa: E731
    zero_phase = ex.multisine(t, 1.0, np.arange(1, k + 1), 1.0, phases=np.zeros(k))
    assert crest(zero_phase) == pytest.approx(math.sqrt(2 * k), rel=1e-9)  # all cosines peak together
    assert crest(ex.multisine(t, 1.0, np.arange(1, k + 1), 1.0)) < 2.0
    np.testing.assert_allclose(ex.schroeder_phases(np.ones(5)), -np.pi * np.arange(1, 6) * np.arange(0, 5) / 5)


def test_multisine_random_phases_seeded():
    t = np.arange(500) / 500
    first = ex.multisine(t, 1.0, [1, 2, 3], phases="random", seed=3)
    assert np.array_equal(first, ex.multisine(t, 1.0, [1, 2, 3], phases="random", seed=3))
    assert not np.array_equal(first, ex.multisine(t, 1.0, [1, 2, 3], phases="random", seed=4))


@pytest.mark.parametrize("n_bits", [5, 7, 10])
def test_max_length_sequence_properties(n_bits):
    n = 2**n_bits - 1
    seq = ex.max_length_sequence(n_bits, seed=11)
    assert seq.size == n
    assert np.sum(seq > 0) == 2 ** (n_bits - 1) and np.sum(seq < 0) == 2 ** (n_bits - 1) - 1
    circular = np.real(np.fft.ifft(np.abs(np.fft.fft(seq)) ** 2))
    assert circular[0] == pytest.approx(n)
    np.testing.assert_allclose(circular[1:], -1.0, atol=1e-8)
    other = ex.max_length_sequence(n_bits, seed=12)
    shifts = [k for k in range(n) if np.array_equal(np.roll(seq, k), other)]
    assert len(shifts) == 1  # another seed gives a cyclic shift of the same sequence


def test_prbs_on_time_grid_holds_bits_and_repeats():
    ts, clock, n_bits = 5e-4, 1e-3, 6
    period = (2**n_bits - 1) * clock
    t = np.arange(round(2 * period / ts)) * ts
    x = ex.prbs(t, n_bits, clock, amplitude=2.0, seed=5, offset=1.0)
    assert set(np.unique(x)) == {-1.0, 3.0}
    half = t.size // 2
    assert np.array_equal(x[:half], x[half:])
    assert np.array_equal(x[0::2], x[1::2])  # each bit held for two samples
    assert np.array_equal(x, ex.prbs(t, n_bits, clock, amplitude=2.0, seed=5, offset=1.0))


# ---------------------------------------------------------------- step and bang-bang


def test_step():
    t = np.arange(10) * 0.1
    np.testing.assert_array_equal(ex.step(t, 0.45, 2.0, initial=1.0), [1, 1, 1, 1, 1, 3, 3, 3, 3, 3])


@pytest.mark.parametrize("distance", [0.3, -0.3, 0.01])
def test_bang_bang_move_integrates_its_acceleration(distance):
    vmax, amax, t0 = 0.2, 2.0, 0.05
    dt = 1e-5
    t = np.arange(0, 2.5, dt)
    p = ex.bang_bang_move(t, distance, vmax, amax, t0, start=0.1)
    # Away from the switching instants (where the acceleration is constant over the stencil), central
    # differences of a piecewise quadratic are exact: the position's derivatives must be the returned ones.
    smooth = np.flatnonzero(
        (p.acceleration[:-4] == p.acceleration[2:-2]) & (p.acceleration[4:] == p.acceleration[2:-2])
    ) + 2
    fd_velocity = (p.position[smooth + 1] - p.position[smooth - 1]) / (2 * dt)
    fd_acceleration = (p.velocity[smooth + 1] - p.velocity[smooth - 1]) / (2 * dt)
    np.testing.assert_allclose(fd_velocity, p.velocity[smooth], atol=1e-9)
    np.testing.assert_allclose(fd_acceleration, p.acceleration[smooth], atol=1e-6)
    assert np.abs(np.diff(p.velocity)).max() <= amax * dt * (1 + 1e-9)  # velocity continuous
    assert p.position[-1] == pytest.approx(0.1 + distance, abs=1e-15)
    assert set(np.unique(np.abs(p.acceleration))) <= {0.0, amax}
    duration = ex.bang_bang_move_time(distance, vmax, amax)
    moving = t[np.abs(p.velocity) > 0]
    assert moving[-1] - moving[0] == pytest.approx(duration, abs=2 * dt)
    middle = ex.bang_bang_move(np.array([t0 + duration / 2]), distance, vmax, amax, t0, start=0.1)
    peak = min(vmax, math.sqrt(abs(distance) * amax))
    assert abs(middle.velocity[0]) == pytest.approx(peak, rel=1e-12)
    assert middle.position[0] == pytest.approx(0.1 + distance / 2, abs=1e-15)


def test_bang_bang_sequence_visits_positions_with_dwell():
    positions, vmax, amax, dwell, t0 = [0.0, 0.15, 0.02, 0.2], 0.2, 2.0, 0.2, 0.1
    t = np.arange(0, 4.0, 1e-4)
    p = ex.bang_bang_sequence(t, positions, vmax, amax, dwell, t0)
    end = t0
    for previous, target in zip(positions[:-1], positions[1:]):
        end += ex.bang_bang_move_time(target - previous, vmax, amax)
        resting = (t >= end) & (t < end + dwell)
        np.testing.assert_allclose(p.position[resting], target, atol=1e-12)
        assert np.all(p.velocity[resting] == 0)
        end += dwell


# ---------------------------------------------------------------- experiment files


def test_example_experiments_load_and_generate():
    files = sorted(EXPERIMENTS.glob("*.toml"))
    kinds = {xp.load_experiment(f).kind for f in files}
    assert {"end_effector_point_to_point", "swept_sine", "fourier", "multisine", "prbs", "bang_bang"} <= kinds
    for path in files:
        experiment = xp.load_experiment(path)
        signals = experiment.generate()
        assert ("jerk" in signals) == (experiment.kind in xp.TRAJECTORY_KINDS)
        assert signals["time"].size == round(experiment.duration / experiment.sample_time)
        assert all(np.all(np.isfinite(v)) for v in signals.values())


def test_experiment_recording_round_trip(tmp_path):
    from motiontwin.harness import recording

    experiment = xp.load_experiment(EXPERIMENTS / "prbs.toml")
    rec = xp.experiment_recording(experiment)
    recording.write_recording(tmp_path / "prbs.csv", rec)
    back = recording.read_recording(tmp_path / "prbs.csv")
    np.testing.assert_array_equal(back["value"], experiment.generate()["value"])
    assert back.meta["seed"] == 7 and back.meta["excited"]["kind"] == "prbs"
    assert back.sample_time == experiment.sample_time
    multi = xp.experiment_recording(xp.load_experiment(EXPERIMENTS / "substrate_alignment.toml"))
    assert {"position_1", "position_4", "jerk_4"} <= set(multi.columns)


def test_swept_sine_example_matches_direct_call():
    experiment = xp.load_experiment(EXPERIMENTS / "swept_sine_80_500.toml")
    signals = experiment.generate()
    direct = ex.swept_sine(signals["time"], 80.0, 500.0, 2.0, 5.0, "linear", 0.1, 0.02)
    assert experiment.target == "u_ext"
    np.testing.assert_array_equal(signals["value"], direct)


def test_fourier_example_duration_is_whole_periods():
    experiment = xp.load_experiment(EXPERIMENTS / "fourier_periodic.toml")
    assert experiment.duration == pytest.approx(10.0)
    position = experiment.generate()["position"]
    per_period = round(1 / (experiment.parameters["f_fundamental"] * experiment.sample_time))
    blocks = position.reshape(10, per_period)
    np.testing.assert_allclose(blocks, blocks[:1].repeat(10, axis=0), atol=1e-12)


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "experiment.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "body,field",
    [
        ('sample_time = 0.001\nduration = 1.0\n[excitation]\nkind = "chirp"\n', "excitation.kind"),
        ('sample_time = 0.001\nduration = 1.0\n[excitation]\nf_start = 1.0\n', "excitation.kind"),
        (
            'sample_time = 0.001\nduration = 1.0\n[excitation]\nkind = "swept_sine"\nf_start = 80.0\n'
            "sweep_time = 1.0\namplitude = 1.0\n",
            "excitation.f_end",
        ),
        (
            'sample_time = 0.001\nduration = 1.0\n[excitation]\nkind = "step"\nt_step = 0.1\namplitude = 1.0\n'
            "amplitud = 2.0\n",
            "excitation.amplitud",
        ),
        ('sample_time = 0.001\nduration = 1.0\n[excitation]\nkind = "step"\nt_step = "soon"\namplitude = 1.0\n',
         "excitation.t_step"),
        ('duration = 1.0\n[excitation]\nkind = "step"\nt_step = 0.1\namplitude = 1.0\n', "sample_time"),
        ('sample_time = 0.001\n[excitation]\nkind = "step"\nt_step = 0.1\namplitude = 1.0\n', "duration"),
        ('sample_time = 0.001\nduration = 1.0\nsample_rate = 5\n[excitation]\nkind = "step"\nt_step = 0.1\n'
         "amplitude = 1.0\n", "sample_rate"),
        ('sample_time = 0.001\n[excitation]\nkind = "fourier"\nf_fundamental = 3.0\nn_periods = 2\n'
         "a = [1.0]\nb = [1.0]\n", "excitation.f_fundamental"),
    ],
)
def test_bad_experiment_files_name_file_and_field(tmp_path, body, field):
    path = write(tmp_path, body)
    with pytest.raises(xp.ExperimentError) as info:
        xp.load_experiment(path)
    assert str(path) in str(info.value)
    assert f"'{field}'" in str(info.value)


def test_invalid_toml_names_file(tmp_path):
    path = write(tmp_path, "sample_time = = 1\n")
    with pytest.raises(xp.ExperimentError, match="invalid TOML.*line 1"):
        xp.load_experiment(path)


# ---------------------------------------------------------------- measurement realism


def test_quantisation_error_bounded_by_half_a_count():
    resolution = 1e-7
    x = np.linspace(-3e-4, 5e-4, 200001)
    q = ms.quantize(x, resolution)
    assert np.abs(q - x).max() <= resolution / 2 * (1 + 1e-9)
    counts = q / resolution
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    # A slow ramp spreads the error uniformly over one count: standard deviation resolution / sqrt(12).
    assert np.std(q - x) == pytest.approx(resolution / math.sqrt(12), rel=0.01)


def test_noise_standard_deviation_within_statistical_bounds():
    n, std = 100_000, 2e-6
    x = np.zeros(n)
    noisy = ms.add_noise(x, std, rng=42)
    # Sample std has relative standard error 1/sqrt(2n); the mean has std/sqrt(n). Use 5-sigma bounds.
    assert abs(noisy.std() / std - 1) < 5 / math.sqrt(2 * n)
    assert abs(noisy.mean()) < 5 * std / math.sqrt(n)
    assert np.array_equal(noisy, ms.add_noise(x, std, rng=42))
    assert not np.array_equal(noisy, ms.add_noise(x, std, rng=43))


def test_encoder_combines_noise_and_counts():
    x = np.full(50_000, 1.23456789e-3)
    y = ms.encoder(x, 1e-6, noise_std=3e-6, rng=np.random.default_rng(1))
    np.testing.assert_allclose(y / 1e-6, np.round(y / 1e-6), atol=1e-6)
    assert y.std() == pytest.approx(math.sqrt(3e-6**2 + 1e-6**2 / 12), rel=0.03)


def test_lowpass_disturbance_variance_and_correlation():
    n, std, bandwidth, ts = 200_000, 0.5, 10.0, 5e-4
    y = ms.lowpass_noise(n, std, bandwidth, ts, rng=9)
    a = math.exp(-2 * math.pi * bandwidth * ts)
    effective = n * (1 - a) / (1 + a)  # independent samples of an AR(1) process for variance estimation
    assert abs(y.std() / std - 1) < 5 / math.sqrt(2 * effective)
    lag1 = np.corrcoef(y[1:], y[:-1])[0, 1]
    assert lag1 == pytest.approx(a, abs=5 * math.sqrt((1 - a**2) / n) + 1e-3)


def test_force_disturbance_deterministic_parts():
    t = np.arange(1000) * 1e-3
    f = ms.force_disturbance(t, offset=0.5, steps=[(0.3, 1.0), (0.6, -2.0)], sine=(0.2, 5.0))
    expected = 0.5 + (t >= 0.3) * 1.0 - (t >= 0.6) * 2.0 + 0.2 * np.sin(2 * np.pi * 5.0 * t)
    np.testing.assert_allclose(f, expected, atol=1e-15)
    noisy = ms.force_disturbance(t, std=0.1, rng=1)
    assert np.array_equal(noisy, ms.force_disturbance(t, std=0.1, rng=1))
