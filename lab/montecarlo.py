"""Monte Carlo estimators, variance reduction and sampling methods of the seed's first half.

Everything here is pure and vectorised: an estimator draws all samples of all repetitions as one
NumPy array (shape ``(repetitions, n)``) from an explicitly seeded ``numpy.random.Generator`` and
returns one estimate per repetition. ``lab/mc_study.py`` runs these over many ``n`` and writes
plots; the tests check them against closed forms.

The seed's integral
-------------------
The slides print ``∫_0^10 sin(√(π²/10) x) / (√(π²/10) x) · e^(√(π²/10) x) dx`` with exact value
``(10 e^π + 10) / π² = 24.45963551499059``. Read literally (k x with k = √(π²/10)) that integral is
511.75, so the radical must extend over x, as the PDF-to-text extraction lost: with
``u(x) = √(π² x / 10) = π √(x/10)`` the substitution ``x = 10 u² / π²`` turns
``∫_0^10 sin(u)/u · e^u dx`` into ``20/π² ∫_0^π sin(u) e^u du = (10 e^π + 10) / π²`` exactly.
So :func:`seed_integrand` is ``sin(u)/u · e^u`` with ``u = π √(x/10)``; its CDF is closed-form too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist
from typing import Callable

import numpy as np


Integrand = Callable[[np.ndarray], np.ndarray]
"""A vectorised real function: array of points in, array of values of the same shape out."""

SEED_INTERVAL: tuple[float, float] = (0.0, 10.0)
SEED_EXACT: float = (10.0 * math.exp(math.pi) + 10.0) / math.pi**2
"""(10 e^π + 10) / π² = 24.45963551499059, the seed's exact value."""


# --------------------------------------------------------------------------------------------
# The seed's integrand
# --------------------------------------------------------------------------------------------


def _seed_u(x: np.ndarray) -> np.ndarray:
    return math.pi * np.sqrt(np.asarray(x, dtype=float) / 10.0)


def seed_integrand(x: np.ndarray) -> np.ndarray:
    """f(x) = sin(u)/u · e^u with u = π √(x/10), for x in [0, 10]; f(0) = 1, f(10) = 0, max ≈ 3.36."""
    u = _seed_u(x)
    # np.sinc(t) = sin(π t)/(π t) handles u = 0 without a special case.
    return np.sinc(u / math.pi) * np.exp(u)


def _seed_antiderivative_in_u(u: np.ndarray) -> np.ndarray:
    # ∫ sin(u) e^u du = e^u (sin u − cos u) / 2
    return np.exp(u) * (np.sin(u) - np.cos(u)) / 2.0


def seed_integrand_cdf(x: np.ndarray) -> np.ndarray:
    """CDF of the density f(x)/F on [0, 10] (0 below, 1 above), in closed form."""
    u = _seed_u(np.clip(x, *SEED_INTERVAL))
    total = (math.exp(math.pi) + 1.0) / 2.0
    return (_seed_antiderivative_in_u(u) + 0.5) / total


def seed_density(x: np.ndarray) -> np.ndarray:
    """The seed's integrand normalised to a pdf on [0, 10], zero outside (a target for the samplers)."""
    x = np.asarray(x, dtype=float)
    inside = (x >= SEED_INTERVAL[0]) & (x <= SEED_INTERVAL[1])
    return np.where(inside, seed_integrand(np.clip(x, *SEED_INTERVAL)) / SEED_EXACT, 0.0)


# --------------------------------------------------------------------------------------------
# 1-D estimators, each returning one estimate per repetition
# --------------------------------------------------------------------------------------------


def uniform_estimates(
    f: Integrand, a: float, b: float, n: int, repetitions: int, rng: np.random.Generator
) -> np.ndarray:
    """The seed's unbiased estimator F_n = (b − a)/n Σ f(X_i), X_i ~ U(a, b); shape (repetitions,)."""
    x = rng.uniform(a, b, size=(repetitions, n))
    return (b - a) * f(x).mean(axis=1)


def biased_max_estimates(
    f: Integrand, a: float, b: float, n: int, repetitions: int, rng: np.random.Generator
) -> np.ndarray:
    """The seed's biased estimator F^β_n = ½ max{f(X_1), …, f(X_n)}, X_i ~ U(a, b), exactly as printed.

    It converges to ½ max f (≈ 1.68 on the seed's integrand), not to the integral: the slides use it
    only to show an error curve that levels off and an MSE dominated by bias².
    """
    x = rng.uniform(a, b, size=(repetitions, n))
    return 0.5 * f(x).max(axis=1)


def stratified_estimates(
    f: Integrand, a: float, b: float, n: int, repetitions: int, rng: np.random.Generator
) -> np.ndarray:
    """Stratified (jittered) sampling: n equal strata of [a, b], one uniform sample in each.

    Unbiased; for a smooth f the variance falls as n⁻³ instead of n⁻¹ because each stratum only
    sees the variation of f across a width (b − a)/n.
    """
    jitter = rng.random((repetitions, n))
    x = a + (np.arange(n) + jitter) * ((b - a) / n)
    return (b - a) * f(x).mean(axis=1)


@dataclass(frozen=True)
class PiecewiseLinearPdf:
    """A pdf proportional to the linear interpolation of ``values`` at increasing ``nodes``.

    Fitted to an integrand by evaluating it at a few nodes, it follows the integrand's shape while its
    CDF stays a piecewise quadratic with a closed-form inverse, so sampling is an exact inverse
    transform. Values must be ≥ 0 with a positive total area.
    """

    nodes: np.ndarray
    values: np.ndarray

    def __post_init__(self) -> None:
        nodes = np.asarray(self.nodes, dtype=float)
        values = np.asarray(self.values, dtype=float)
        if nodes.ndim != 1 or nodes.shape != values.shape or nodes.size < 2:
            raise ValueError("nodes and values must be 1-D arrays of the same length >= 2")
        if np.any(np.diff(nodes) <= 0) or np.any(values < 0) or not np.any(values > 0):
            raise ValueError("nodes must increase and values must be >= 0, not all zero")
        object.__setattr__(self, "nodes", nodes)
        object.__setattr__(self, "values", values)

    @classmethod
    def fit(cls, f: Integrand, a: float, b: float, segments: int) -> PiecewiseLinearPdf:
        """Interpolate f at ``segments + 1`` equally spaced nodes of [a, b]."""
        nodes = np.linspace(a, b, segments + 1)
        return cls(nodes, f(nodes))

    @property
    def _segment_areas(self) -> np.ndarray:
        return np.diff(self.nodes) * (self.values[:-1] + self.values[1:]) / 2.0

    @property
    def _cumulative_areas(self) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(self._segment_areas)])

    def pdf(self, x: np.ndarray) -> np.ndarray:
        """Density at x (zero outside [nodes[0], nodes[-1]])."""
        x = np.asarray(x, dtype=float)
        density = np.interp(x, self.nodes, self.values, left=0.0, right=0.0)
        return density / self._cumulative_areas[-1]

    def cdf(self, x: np.ndarray) -> np.ndarray:
        """Closed-form CDF: whole segments below x plus the trapezoid up to x in x's segment."""
        x = np.clip(np.asarray(x, dtype=float), self.nodes[0], self.nodes[-1])
        segment = np.clip(np.searchsorted(self.nodes, x, side="right") - 1, 0, self.nodes.size - 2)
        left = self.nodes[segment]
        value_left = self.values[segment]
        value_x = np.interp(x, self.nodes, self.values)
        partial = (x - left) * (value_left + value_x) / 2.0
        cumulative = self._cumulative_areas
        return (cumulative[segment] + partial) / cumulative[-1]

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...]) -> np.ndarray:
        """Inverse transform: pick a segment by its area, then invert its quadratic CDF."""
        xi = rng.random(size)
        cumulative = self._cumulative_areas / self._cumulative_areas[-1]
        segment = np.clip(np.searchsorted(cumulative, xi, side="right") - 1, 0, self.nodes.size - 2)
        # Reuse ξ rescaled inside the chosen segment (ζ in [0, 1)): one uniform per sample.
        zeta = (xi - cumulative[segment]) / (cumulative[segment + 1] - cumulative[segment])
        v0 = self.values[segment]
        v1 = self.values[segment + 1]
        # Density ∝ v0 + (v1 − v0) t on t in [0, 1]; CDF(t) = ζ solves
        # (v1 − v0)/2 t² + v0 t − ζ (v0 + v1)/2 = 0.
        # This root form stays accurate when v1 ≈ v0 (no cancellation, no division by v1 − v0).
        rhs = zeta * (v0 + v1)
        denominator = v0 + np.sqrt(v0 * v0 + (v1 - v0) * rhs)
        t = np.divide(rhs, denominator, out=np.zeros_like(rhs), where=denominator > 0)
        width = self.nodes[segment + 1] - self.nodes[segment]
        return self.nodes[segment] + np.clip(t, 0.0, 1.0) * width


def importance_estimates(
    f: Integrand, pdf: PiecewiseLinearPdf, n: int, repetitions: int, rng: np.random.Generator
) -> np.ndarray:
    """Importance sampling F_n = 1/n Σ f(X_i)/p(X_i), X_i ~ p; shape (repetitions,).

    Unbiased as long as p > 0 wherever f ≠ 0; its variance is small when f/p is nearly constant.
    """
    x = pdf.sample(rng, (repetitions, n))
    return (f(x) / pdf.pdf(x)).mean(axis=1)


# --------------------------------------------------------------------------------------------
# A 2-D integrand with an expensive and a cheap dimension: Russian roulette and splitting
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ExpensiveCheapIntegrand:
    """g(x, y) = L(y) · w(x, y) on [0, 1]², a toy of direct lighting in a path tracer.

    L(y) = (π/2) sin(π y) is the *expensive* factor (think: radiance found by tracing a ray for the
    sample y), costing ``expensive_cost`` units per evaluation; w(x, y) = (k+1) frac(x + y)^k is the
    *cheap* factor (think: an analytic BSDF lobe), costing ``cheap_cost``. For every y, frac(x + y) is
    uniform when x is, so ∫ w dx = 1 and the exact value is ∫ L dy = 1 although x and y are coupled.
    Since w is small for most x, Russian roulette can skip most L evaluations there; since most of
    the variance comes from x, splitting (several cheap x per expensive y) pays.
    Efficiency uses these cost units rather than wall time: NumPy overhead would swamp a toy L.
    """

    lobe_exponent: int = 4
    cheap_cost: float = 1.0
    expensive_cost: float = 10.0
    exact: float = 1.0

    def expensive_factor(self, y: np.ndarray) -> np.ndarray:
        return (math.pi / 2.0) * np.sin(math.pi * y)

    def cheap_factor(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return (self.lobe_exponent + 1) * np.mod(x + y, 1.0) ** self.lobe_exponent

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return self.expensive_factor(y) * self.cheap_factor(x, y)


@dataclass(frozen=True)
class CostedEstimates:
    """Estimates of R repetitions and their mean cost per estimate, in the integrand's cost units."""

    estimates: np.ndarray
    cost_per_estimate: float


def uniform_2d_estimates(
    g: ExpensiveCheapIntegrand, n: int, repetitions: int, rng: np.random.Generator
) -> CostedEstimates:
    """Plain MC on [0, 1]²: n samples, each evaluating both factors once."""
    x = rng.random((repetitions, n))
    y = rng.random((repetitions, n))
    estimates = g(x, y).mean(axis=1)
    return CostedEstimates(estimates, n * (g.cheap_cost + g.expensive_cost))


def russian_roulette_estimates(
    g: ExpensiveCheapIntegrand,
    n: int,
    repetitions: int,
    rng: np.random.Generator,
    weight_threshold: float = 0.5,
    survival_probability: float = 0.1,
) -> CostedEstimates:
    """Russian roulette: where the cheap weight w < ``weight_threshold``, evaluate the expensive L
    only with probability q = ``survival_probability`` and divide the survivors by q.

    Unbiased (E[contribution] = q · g/q + (1 − q) · 0 = g); it trades a little variance for skipping
    most expensive evaluations of samples that contribute little.
    """
    x = rng.random((repetitions, n))
    y = rng.random((repetitions, n))
    roulette = rng.random((repetitions, n))
    weight = g.cheap_factor(x, y)
    played = weight < weight_threshold
    survives = ~played | (roulette < survival_probability)
    contribution = np.zeros_like(weight)
    # Evaluate the expensive factor on survivors only: that is the whole point of the method.
    contribution[survives] = g.expensive_factor(y[survives]) * weight[survives]
    contribution[played & survives] /= survival_probability
    expensive_evaluations = survives.sum() / repetitions
    cost = n * g.cheap_cost + expensive_evaluations * g.expensive_cost
    return CostedEstimates(contribution.mean(axis=1), float(cost))


def splitting_estimates(
    g: ExpensiveCheapIntegrand, n: int, repetitions: int, rng: np.random.Generator, splits: int = 8
) -> CostedEstimates:
    """Splitting: n expensive samples y, each shared by ``splits`` cheap samples x.

    F = 1/n Σ_i L(Y_i) · 1/m Σ_j w(X_ij, Y_i): unbiased, and the variance due to x shrinks by m at
    the price of m cheap evaluations instead of m expensive ones.
    """
    y = rng.random((repetitions, n))
    x = rng.random((repetitions, n, splits))
    mean_weight = g.cheap_factor(x, y[..., np.newaxis]).mean(axis=2)
    estimates = (g.expensive_factor(y) * mean_weight).mean(axis=1)
    return CostedEstimates(estimates, n * (g.expensive_cost + splits * g.cheap_cost))


# --------------------------------------------------------------------------------------------
# Statistics over repetitions
# --------------------------------------------------------------------------------------------


def run_repetitions(
    estimator: Callable[[int, int, np.random.Generator], np.ndarray],
    n: int,
    repetitions: int,
    rng: np.random.Generator,
    max_elements: int = 1 << 21,
) -> np.ndarray:
    """Call ``estimator(n, batch, rng)`` on batches of repetitions so no array exceeds ``max_elements``
    samples (bounded memory at large n), and concatenate the estimates."""
    batch = max(1, max_elements // max(n, 1))
    chunks = [
        estimator(n, min(batch, repetitions - start), rng) for start in range(0, repetitions, batch)
    ]
    return np.concatenate(chunks)


def normal_quantile(confidence: float) -> float:
    """z such that a normal variable lies within ±z with probability ``confidence``."""
    return NormalDist().inv_cdf(0.5 + confidence / 2.0)


@dataclass(frozen=True)
class RepetitionStatistics:
    """Sample statistics of R independent estimates of a known exact value.

    ``variance`` and ``mse`` are plug-in means (divided by R, not R − 1) so that
    ``mse == variance + bias**2`` holds exactly as an identity of the sample, mirroring
    MSE = V + β². Each ``*_half_width`` is a normal-approximation (CLT) confidence half-width at
    ``confidence``; for variance and MSE it is the CLT on the squared deviations, which does not
    assume normally distributed estimates.
    """

    repetitions: int
    confidence: float
    mean: float
    mean_half_width: float
    variance: float
    variance_half_width: float
    bias: float
    mse: float
    mse_half_width: float

    def contains(self, value: float) -> bool:
        """Whether ``value`` lies in the confidence interval of the mean."""
        return abs(self.mean - value) <= self.mean_half_width


def summarize_repetitions(
    estimates: np.ndarray, exact: float, confidence: float = 0.999
) -> RepetitionStatistics:
    """Mean, variance, bias and MSE of ``estimates`` with confidence half-widths."""
    estimates = np.asarray(estimates, dtype=float)
    repetitions = estimates.size
    if repetitions < 2:
        raise ValueError("need at least two repetitions")
    z = normal_quantile(confidence)
    root_r = math.sqrt(repetitions)
    mean = float(estimates.mean())
    squared_deviations = (estimates - mean) ** 2
    squared_errors = (estimates - exact) ** 2
    return RepetitionStatistics(
        repetitions=repetitions,
        confidence=confidence,
        mean=mean,
        mean_half_width=z * float(estimates.std(ddof=1)) / root_r,
        variance=float(squared_deviations.mean()),
        variance_half_width=z * float(squared_deviations.std(ddof=1)) / root_r,
        bias=mean - exact,
        mse=float(squared_errors.mean()),
        mse_half_width=z * float(squared_errors.std(ddof=1)) / root_r,
    )


def loglog_slope(
    n: np.ndarray, values: np.ndarray, standard_errors: np.ndarray
) -> tuple[float, float]:
    """Weighted least-squares slope of log(values) against log(n) and its standard error.

    The standard error of log(value) is taken as ``standard_error / value`` (delta method), so a
    slope test's tolerance follows from the number of repetitions behind each value.
    """
    log_n = np.log(np.asarray(n, dtype=float))
    values = np.asarray(values, dtype=float)
    log_values = np.log(values)
    weights = (values / np.asarray(standard_errors, dtype=float)) ** 2
    centre = np.average(log_n, weights=weights)
    spread = float(np.sum(weights * (log_n - centre) ** 2))
    slope = float(np.sum(weights * (log_n - centre) * log_values) / spread)
    return slope, 1.0 / math.sqrt(spread)


# --------------------------------------------------------------------------------------------
# Sampling methods
# --------------------------------------------------------------------------------------------


def sample_cosine_hemisphere(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The seed's inverse transform for a Lambertian BRDF: φ = 2π ξ₁, θ = arccos √(1 − ξ₂), run by the
    renderer's own compiled warp (core.warps.sample_cos_hemisphere_local, which the diffuse BSDF samples with).

    Returns (θ, φ): θ has pdf sin 2θ on [0, π/2] (CDF sin²θ), φ is uniform on [0, 2π); the
    solid-angle pdf is cos θ / π.
    """
    xi_phi = rng.random(n)
    xi_theta = rng.random(n)
    from ..core import warps  # numba: imported when used (`monte` builds its parser from lab.mc_study)

    w = warps.cos_hemisphere_local_many(np.column_stack([xi_theta, xi_phi]))
    return np.arccos(np.clip(w[:, 2], -1.0, 1.0)), np.arctan2(w[:, 1], w[:, 0]) % (2.0 * math.pi)


def cosine_hemisphere_theta_pdf(theta: np.ndarray) -> np.ndarray:
    """pdf of the polar angle of cosine-weighted directions: sin 2θ on [0, π/2]."""
    return np.sin(2.0 * np.asarray(theta))


def cosine_hemisphere_theta_cdf(theta: np.ndarray) -> np.ndarray:
    return np.sin(np.clip(theta, 0.0, math.pi / 2.0)) ** 2


def uniform_hemisphere_theta_pdf(theta: np.ndarray) -> np.ndarray:
    """pdf of the polar angle of *uniform* hemisphere directions, sin θ: the wrong pdf for a check."""
    return np.sin(np.asarray(theta))


def uniform_hemisphere_theta_cdf(theta: np.ndarray) -> np.ndarray:
    return 1.0 - np.cos(np.clip(theta, 0.0, math.pi / 2.0))


def directions_from_angles(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Unit vectors (n, 3) around +z from polar angle θ and azimuth φ."""
    sin_theta = np.sin(theta)
    return np.stack([sin_theta * np.cos(phi), sin_theta * np.sin(phi), np.cos(theta)], axis=-1)


@dataclass(frozen=True)
class RejectionResult:
    samples: np.ndarray
    acceptance_rate: float


def envelope_constant(
    target_pdf: Integrand,
    proposal_pdf: Integrand,
    a: float,
    b: float,
    grid_points: int = 100_001,
    margin: float = 1.02,
) -> float:
    """M ≥ sup target/proposal on [a, b], from a fine grid times a safety ``margin``.

    A grid maximum of a smooth ratio is within a hair of the true one; the margin covers that hair,
    and :func:`rejection_sample` raises if a sample ever exceeds the envelope anyway.
    """
    x = np.linspace(a, b, grid_points)
    proposal = proposal_pdf(x)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(proposal > 0, target_pdf(x) / proposal, 0.0)
    return margin * float(ratio.max())


def rejection_sample(
    target_pdf: Integrand,
    proposal_sample: Callable[[np.random.Generator, int], np.ndarray],
    proposal_pdf: Integrand,
    envelope: float,
    n: int,
    rng: np.random.Generator,
) -> RejectionResult:
    """Acceptance-rejection: draw X ~ q, accept when U · M · q(X) ≤ p(X); repeat until n accepted.

    Works in batches sized by the expected acceptance rate 1/M, so the Python loop runs over a few
    batches, not over samples.
    """
    accepted: list[np.ndarray] = []
    have = 0
    proposed = 0
    while have < n:
        batch = int(math.ceil((n - have) * envelope * 1.1)) + 16
        x = proposal_sample(rng, batch)
        target = target_pdf(x)
        bound = envelope * proposal_pdf(x)
        if np.any(target > bound):
            raise ValueError("the envelope M·q does not bound the target pdf; raise M")
        keep = rng.random(batch) * bound <= target
        accepted.append(x[keep])
        have += int(keep.sum())
        proposed += batch
    samples = np.concatenate(accepted)[:n]
    return RejectionResult(samples, acceptance_rate=have / proposed)


@dataclass(frozen=True)
class MetropolisResult:
    samples: np.ndarray
    acceptance_rate: float


def metropolis_hastings(
    target_density: Integrand,
    initial_states: np.ndarray,
    step_size: float,
    steps: int,
    rng: np.random.Generator,
) -> MetropolisResult:
    """Random-walk Metropolis-Hastings on many independent chains at once.

    Each chain starts at its ``initial_states`` entry (the target density must be positive there)
    and takes ``steps`` Gaussian proposals x' = x + σ N(0, 1), accepted with probability
    min(1, p(x')/p(x)); the proposal is symmetric so the Hastings ratio is just p(x')/p(x).
    ``target_density`` may be unnormalised and zero outside its support (such moves are rejected).
    Returns each chain's final state: states of different chains are independent, so a chi-square
    test on them is valid, which it would not be on consecutive (correlated) states of one chain.
    The Python loop runs over steps; each step advances all chains as one array.
    """
    states = np.array(initial_states, dtype=float)
    density = target_density(states)
    if np.any(density <= 0):
        raise ValueError("every chain must start where the target density is positive")
    accepted = 0
    for _ in range(steps):
        proposal = states + step_size * rng.standard_normal(states.shape)
        proposal_density = target_density(proposal)
        accept = rng.random(states.shape) * density < proposal_density
        states = np.where(accept, proposal, states)
        density = np.where(accept, proposal_density, density)
        accepted += int(accept.sum())
    return MetropolisResult(states, acceptance_rate=accepted / (steps * states.size))


# --------------------------------------------------------------------------------------------
# Goodness of fit
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ChiSquareResult:
    statistic: float
    p_value: float
    degrees_of_freedom: int
    bins: int


def chi_square_test(
    observed: np.ndarray, expected_probabilities: np.ndarray, min_expected: float = 5.0
) -> ChiSquareResult:
    """Pearson's chi-square test of counts against bin probabilities (any shape, flattened in order).

    Bins expected to hold fewer than ``min_expected`` samples are merged with their neighbours
    first: the chi-square approximation of the statistic's distribution needs populated bins.
    """
    from scipy import stats  # lazy: importing this module should stay cheap

    counts = np.asarray(observed, dtype=float).ravel()
    probabilities = np.asarray(expected_probabilities, dtype=float).ravel()
    if not math.isclose(probabilities.sum(), 1.0, rel_tol=1e-9, abs_tol=1e-9):
        raise ValueError(f"bin probabilities sum to {probabilities.sum()}, not 1: bins miss support")
    total = counts.sum()
    merged_counts: list[float] = []
    merged_expected: list[float] = []
    count_acc = expected_acc = 0.0
    for count, probability in zip(counts, probabilities):
        count_acc += count
        expected_acc += probability * total
        if expected_acc >= min_expected:
            merged_counts.append(count_acc)
            merged_expected.append(expected_acc)
            count_acc = expected_acc = 0.0
    if merged_expected:  # fold an under-populated tail into the last bin
        merged_counts[-1] += count_acc
        merged_expected[-1] += expected_acc
    if len(merged_expected) < 2:
        raise ValueError("too few samples for a chi-square test with these bins")
    statistic, p_value = stats.chisquare(merged_counts, merged_expected)
    return ChiSquareResult(float(statistic), float(p_value), len(merged_expected) - 1, len(merged_expected))


def histogram_chi_square(
    samples: np.ndarray, cdf: Callable[[np.ndarray], np.ndarray], edges: np.ndarray
) -> ChiSquareResult:
    """Chi-square test of 1-D ``samples`` binned at ``edges`` against the distribution with ``cdf``.

    The edges must cover the support (every sample inside, bin probabilities summing to 1).
    """
    observed, _ = np.histogram(samples, bins=edges)
    if observed.sum() != np.asarray(samples).size:
        raise ValueError("some samples fall outside the histogram edges")
    return chi_square_test(observed, np.diff(cdf(np.asarray(edges, dtype=float))))


def cosine_hemisphere_chi_square(
    theta: np.ndarray,
    phi: np.ndarray,
    theta_cdf: Callable[[np.ndarray], np.ndarray] = cosine_hemisphere_theta_cdf,
    theta_bins: int = 10,
    phi_bins: int = 8,
) -> ChiSquareResult:
    """Joint chi-square test of hemisphere directions (θ, φ) against ``theta_cdf`` × uniform φ.

    Testing θ and φ jointly also catches a sampler whose marginals are right but which couples them.
    """
    theta_edges = np.linspace(0.0, math.pi / 2.0, theta_bins + 1)
    phi_edges = np.linspace(0.0, 2.0 * math.pi, phi_bins + 1)
    observed, _, _ = np.histogram2d(theta, phi, bins=[theta_edges, phi_edges])
    expected = np.outer(np.diff(theta_cdf(theta_edges)), np.full(phi_bins, 1.0 / phi_bins))
    return chi_square_test(observed, expected)
