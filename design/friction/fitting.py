"""What the identification steps share (paper Section 3.2): the filters of the measured
signals, the error measure and the statistics of a least-squares solution — 95 % intervals
from s²·(JᵀJ)⁻¹ with s² inflated for autocorrelation, or the cluster-robust covariance of the
output-error segments."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.stats
from scipy.signal import butter, sosfiltfilt

from smartjoint.design.friction.records import Record

WEAK_RELATIVE_WIDTH = 0.5  # 95 % interval wider than ±50 % of the value: weakly identifiable
# Low-pass of the measured excitation force that drives the output-error model, in multiples
# of the excitation frequency: keeps the 4th harmonic, removes the sensor noise at the bristle
# resonance (20–40× the excitation frequency on the rig).
EXCITATION_CUTOFF = 5.0
# A shaker's harmonics from the 4th (which the low-pass attenuates) up to this order are kept
# exactly where they stand out of the spectrum (excitation_drive).
MAX_HARMONIC = 10
HARMONIC_LEVEL = 2e-3  # a harmonic counts from this amplitude relative to the fundamental
VELOCITY_CUTOFF = 25.0  # default of filtered_velocity, which also gives the output-error segment starts


def dominant_frequency(signal, sample_time: float) -> float:
    """The strongest non-zero frequency of a signal [Hz]: the excitation frequency of a rig record.

    Parameters
    ----------
    signal : ndarray
        Equally spaced samples; the mean is removed before the FFT.
    sample_time : float
        Their spacing [s], for the frequency axis.

    Returns
    -------
    float
        The frequency of the largest spectral line above zero [Hz].
    """
    spectrum = np.abs(np.fft.rfft(signal - np.mean(signal)))
    frequencies = np.fft.rfftfreq(len(signal), sample_time)
    return float(frequencies[1:][np.argmax(spectrum[1:])])


def excitation_drive(record: Record) -> tuple[np.ndarray, float]:
    """The measured excitation with its noise removed for the output-error model, and its
    frequency [Hz].

    The force is low-passed at ``EXCITATION_CUTOFF``× the excitation frequency (its noise near
    the bristle resonance, 20–40× the frequency, would shake the simulated bristles), except for
    the shaker's harmonics from the 4th on up to ``MAX_HARMONIC`` whose lines exceed
    ``HARMONIC_LEVEL`` of the fundamental and 20× the spectrum's median: those are fitted as
    sines at their exact frequency and added back unfiltered. Cut off, a 7th harmonic of 5 %
    drives the model with a force the shaker never applied (type A: σ0 +14 %, v_s −13 %);
    passed by a cutoff raised above it, the noise it lets in biases F_d by +27 %.

    Parameters
    ----------
    record : Record
        A record with its excitation force.

    Returns
    -------
    tuple
        (the force for the model, the excitation frequency).
    """
    force = record.excitation_force
    assert force is not None
    time = record.time - record.time[0]
    coarse = dominant_frequency(force, record.sample_time)
    step = 1.0 / (time[-1] + record.sample_time)  # the FFT's bin
    frequency = float(
        scipy.optimize.minimize_scalar(
            lambda f: _line(force, time, f)[1], bounds=(coarse - step, coarse + step), method="bounded"
        ).x
    )
    fundamental = _line(force, time, frequency)[0]
    # 20× the spectrum's median, as a sine amplitude
    floor = 40.0 / force.size * float(np.median(np.abs(np.fft.rfft(force - force.mean()))))
    kept = np.zeros_like(force)
    for order in range(4, MAX_HARMONIC + 1):
        basis = np.column_stack(
            [np.sin(2 * np.pi * order * frequency * time), np.cos(2 * np.pi * order * frequency * time)]
        )
        coefficients = np.linalg.lstsq(basis, force, rcond=None)[0]
        if np.hypot(*coefficients) > max(HARMONIC_LEVEL * fundamental, floor):
            kept += basis @ coefficients
    period = 1.0 / frequency
    return low_pass(force - kept, record.sample_time, EXCITATION_CUTOFF * frequency, period) + kept, frequency


def _line(signal: np.ndarray, time: np.ndarray, frequency: float) -> tuple[float, float]:
    """The least-squares periodic signal of ``frequency`` (its harmonics to ``MAX_HARMONIC``) in
    ``signal``: the fundamental's amplitude and the residual (the harmonics fitted together, or
    they bias the frequency)."""
    phase = 2.0 * np.pi * frequency * time
    orders = np.arange(1, MAX_HARMONIC + 1)
    basis = np.column_stack([np.sin(np.outer(phase, orders)), np.cos(np.outer(phase, orders)), np.ones_like(time)])
    coefficients, residual = np.linalg.lstsq(basis, signal, rcond=None)[:2]
    amplitude = float(np.hypot(coefficients[0], coefficients[MAX_HARMONIC]))
    return amplitude, float(residual[0]) if residual.size else 0.0


def low_pass(signal, sample_time: float, cutoff_hz: float, period: float) -> np.ndarray:
    """Zero-phase 4th-order Butterworth low-pass, padded by one ``period`` [s] at both ends.

    scipy's default padding (a few samples) leaves end transients of the filter's own time
    constant: 150 N on a 330 N sine at 5× its frequency, against 0.01 N with one period.

    Parameters
    ----------
    signal : ndarray
        The samples to filter.
    sample_time : float
        Their spacing [s]: the sample rate 1/Δt sets the filter.
    cutoff_hz : float
        The cutoff [Hz]; at or above 0.45× the sample rate the signal is returned unfiltered.
    period : float
        The padding [s], one period of the excitation.

    Returns
    -------
    ndarray
        The filtered signal.
    """
    fs = 1.0 / sample_time
    if cutoff_hz >= 0.45 * fs:
        return np.asarray(signal, dtype=float)
    sos = butter(4, cutoff_hz, fs=fs, output="sos")
    return sosfiltfilt(sos, signal, padlen=min(int(round(period * fs)), len(signal) - 1))


def filtered_velocity(record: Record, cutoff_hz: float | None = None) -> np.ndarray:
    """Zero-phase low-pass of the measured velocity (default cutoff: 25× the dominant frequency).

    Parameters
    ----------
    record : Record
        The record.
    cutoff_hz : float, optional
        The cutoff [Hz]; default ``VELOCITY_CUTOFF`` × the dominant frequency.

    Returns
    -------
    ndarray
        The filtered sliding velocity.
    """
    dominant = dominant_frequency(record.sliding_velocity, record.sample_time)
    if cutoff_hz is None:
        cutoff_hz = VELOCITY_CUTOFF * dominant
    return low_pass(record.sliding_velocity, record.sample_time, cutoff_hz, 1.0 / dominant)


def smoothed_friction(record: Record) -> np.ndarray:
    """The friction column low-passed at ``VELOCITY_CUTOFF``× the excitation frequency (starts, screening).

    A heavy element's friction column is F_exc − m·a: at 3 % velocity noise its m·a noise
    lies far above the friction itself (type A, 300 kg: start F_c 4.8, F_d 16 for a true 0.8
    and 0.3), while a stick-slip cycle's shape lives well below 25× the excitation frequency.
    """
    signal = record.excitation_force if record.excitation_force is not None else record.friction_force
    frequency = dominant_frequency(signal, record.sample_time)
    if not frequency > 0.0:
        return record.friction_force
    return low_pass(record.friction_force, record.sample_time, VELOCITY_CUTOFF * frequency, 1.0 / frequency)


def rms(x) -> float:
    """Root mean square of a signal.

    Parameters
    ----------
    x : array_like
        The samples.

    Returns
    -------
    float
        √(mean x²).
    """
    return float(np.sqrt(np.mean(np.asarray(x) ** 2)))


def nrmse(measured, model) -> float:
    """Normalised RMS error ‖u − û‖_rms / ‖u‖_rms.

    Parameters
    ----------
    measured, model : ndarray
        The measured and the model signal.

    Returns
    -------
    float
        The error relative to the measured RMS.

    Examples
    --------
    >>> round(nrmse(np.array([1.0, -1.0]), np.array([0.9, -1.1])), 6)
    0.1
    """
    return float(np.sqrt(np.mean((measured - model) ** 2)) / np.sqrt(np.mean(measured**2)))


@dataclass
class StepResult:
    """One identification step: the values, 95 % intervals and correlation of its parameters."""

    names: tuple[str, ...]
    values: np.ndarray
    lower: np.ndarray  # 95 % interval
    upper: np.ndarray
    correlation: np.ndarray
    nrmse: dict[str, float]  # per record: friction force (Eq. 3 steps), sliding velocity (output error)
    cost: float
    evaluations: int

    @property
    def weak(self) -> list[str]:
        with np.errstate(over="ignore"):  # an unbounded interval is simply weak
            width = (self.upper - self.lower) / (2.0 * self.values)
        return [n for n, w in zip(self.names, width) if not w <= WEAK_RELATIVE_WIDTH]


def step_result(names, solution, errors: dict[str, float], evaluations: int, clusters=None) -> StepResult:
    """Values, 95 % intervals and correlation of a log-parameter least-squares ``solution``.

    A parameter the residuals do not see (a null direction of J) or held at a bound gets an
    unbounded interval rather than the zero width a pseudo-inverse would give it.

    Parameters
    ----------
    names : sequence of str
        The parameters, in the order of ``solution.x`` (their logarithms).
    solution : scipy.optimize.OptimizeResult
        From ``least_squares``: ``x``, ``fun``, ``jac``, ``cost``, ``active_mask``.
    errors : dict of str to float
        NRMSE per record.
    evaluations : int
        Residual evaluations spent.
    clusters : ndarray of int, optional
        A group label per residual (output-error segments) for the cluster-robust (sandwich)
        covariance; without it s²·(JᵀJ)⁻¹ with s² inflated for autocorrelation.

    Returns
    -------
    StepResult
    """
    J, r = solution.jac, solution.fun
    _, singular, vt = np.linalg.svd(J, full_matrices=False)
    seen = singular > singular[0] * 1e-8
    inverse = (vt[seen].T / singular[seen] ** 2) @ vt[seen]  # (JᵀJ)⁻¹ on the directions J sees
    if clusters is None:
        dof = max(r.size - len(names), 1)
        # Residuals of neighbouring samples are correlated (smooth signals, filtered inputs):
        # inflate the variance by (1 + ρ)/(1 − ρ), ρ the lag-1 autocorrelation, i.e. count
        # effective rather than nominal samples.
        e = r - r.mean()
        rho = float(np.clip(np.dot(e[1:], e[:-1]) / max(np.dot(e, e), 1e-300), 0.0, 0.999))
        covariance = 2.0 * solution.cost / dof * (1.0 + rho) / (1.0 - rho) * inverse
    else:
        # Errors within a segment share its start value and integrated force noise: each
        # segment is one independent observation of the gradient.
        count = int(clusters.max()) + 1
        gradients = np.zeros((count, len(names)))
        np.add.at(gradients, clusters, J * r[:, None])
        covariance = inverse @ (gradients.T @ gradients) @ inverse * count / max(count - len(names), 1)
    sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    # With few clusters the sandwich's own spread matters: Student's t on count − parameters
    # degrees of freedom instead of the normal quantile (1.96).
    quantile = 1.96 if clusters is None else float(scipy.stats.t.ppf(0.975, max(count - len(names), 1)))
    sigma[np.any(np.abs(vt[~seen]) > 1e-6, axis=0) | (solution.active_mask != 0)] = np.inf
    with np.errstate(invalid="ignore"):
        correlation = np.nan_to_num(covariance / np.outer(np.maximum(sigma, 1e-300), np.maximum(sigma, 1e-300)))
    np.fill_diagonal(correlation, 1.0)
    return StepResult(
        tuple(names),
        np.exp(solution.x),
        np.exp(np.clip(solution.x - quantile * sigma, -700, 700)),
        np.exp(np.clip(solution.x + quantile * sigma, -700, 700)),
        correlation,
        errors,
        float(solution.cost),
        evaluations,
    )


__all__ = [
    "smoothed_friction",
    "EXCITATION_CUTOFF",
    "excitation_drive",
    "StepResult",
    "VELOCITY_CUTOFF",
    "WEAK_RELATIVE_WIDTH",
    "dominant_frequency",
    "filtered_velocity",
    "low_pass",
    "nrmse",
    "rms",
    "step_result",
]
