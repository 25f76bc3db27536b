"""
Partial pooling of a fleet's bias models: the population prior and unit fits shrunk toward it.

Every unit of a fleet is fitted with the same coefficients per axis
(`PoolingDesign`): a bias polynomial of one order in x = (T - reference) /
scale, one reference and scale for the fleet, and, when the fleet shows it,
the temperature-rate coefficient c of the bias c x dT/dt (dT/dt the slope
over the node's 60 s window), which carries a thermal lag to first order.

A record is summarised once, where it is read (`record_moments`): per axis
the normal equations of a wider design (powers 0 to `MOMENT_ORDER` of
(T - 25 C) / 50 C, and dT/dt), and per block of about a minute the row count
and the sums of the rate and of the columns (`DesignMoments`). Any fleet
design of order <= MOMENT_ORDER is a linear map of those columns
(`PoolingDesign.transform`), so the fleet chooses its order and reference
after seeing every unit without reading a record again. A unit of several
records (`unit_moments`) has, as in ``diagnose``, a bias offset of its own per
record (a power cycle or a re-mount): an indicator column per record but the
last, profiled out of the normal equations (each such record's sums taken
about its own means), so the unit's coefficients are those of its last record's
mount, as the params.yaml ``diagnose`` writes carries the last record's offset.

A unit's own estimate is least squares in the fleet design, with information
J = X'X / (kappa sigma^2): sigma^2 its residual variance, kappa >= 1 the
variance inflation of slow noise (bias instability) that the fleet measures
on the residual sums of four-minute stretches (`fleet_kappa`). The
population is beta_i ~ N(mu, Sigma / w_i), w_i = (nu + p) / (nu + d_i^2) the
weight a Student t prior (nu = 4) gives a unit at distance d_i from the
fleet, so a unit far from the others hardly moves mu or Sigma, nor is pulled
toward them. mu and Sigma are estimated by EM in information form
(`fit_population`): with h = X'y / (kappa sigma^2), a unit's posterior is
b = (I + Sigma J / w)^-1 (mu + Sigma h / w), so a record that cannot tell
some coefficients apart (a few degrees of one ramp) needs no inverse of its
J. Sigma is kept from singular by the standard error of a variance at zero,
sqrt(2 / N) (mean J)^-1: units agreeing within their noise (every unit's
temperature-rate coefficient proportional to its slope) do not pin a unit
whose own record says otherwise. `shrink` gives a unit's posterior mean: a
long record (large J) keeps its own fit, a short one takes the fleet's where
its data is silent. The unit's own data then test the shrunk coefficients
b (`ConflictTest`): q = (b - b_own)' J (b - b_own), the rise of its residual
sum of squares from its own fit in its noise kappa sigma^2, is chi^2 with
rank(J) degrees of freedom were b its true coefficients, and smaller for a
unit drawn from the population (at a given weight, a sum of chi^2_1 / (1 +
lambda_k), lambda_k the eigenvalues of J Sigma / w): such a unit is rejected
at most CONFLICT_LEVEL of the time. Where q passes chi^2's 1 - CONFLICT_LEVEL
quantile, the record contradicts what the fleet makes of the unit, and it
keeps its own fit. At any temperature the shrunk bias is within sqrt(q)
standard errors of the own fit's (Cauchy and Schwarz). A long record is
seldom rejected, since the farther a unit is from the fleet the smaller its
t weight, which bounds q; the test catches a record that contradicts the
fleet where the fleet dominates its fit, a short one. Numpy only.
"""

from dataclasses import dataclass, replace
import math

import numpy as np

from ..effects import DEFAULT_RATE_WINDOW_S, TemperatureSlope
from ..errors import CalibrationError

MOMENT_ORDER = 6
MOMENT_REFERENCE_C = 25.0
MOMENT_SCALE_C = 50.0
RATE_WINDOW_S = DEFAULT_RATE_WINDOW_S
# Blocks of the residual sums: a rate window, longer for long records (at most MAX_BLOCKS).
BLOCK_S = RATE_WINDOW_S
MAX_BLOCKS = 256
# kappa merges blocks into stretches this long: slow noise shows over minutes.
KAPPA_STRETCH_S = 4.0 * BLOCK_S
T_DEGREES_OF_FREEDOM = 4.0
# A record tests the temperature rate when, after its first rate window, dT/dt varies: its
# standard deviation at least this fraction of its RMS (one ramp at one rate does not).
RATE_VARIATION = 0.25
# A column enters the fleet design when the units show it at this level (chi^2, one-sided).
SIGNIFICANCE = 0.001
_SIGNIFICANCE_Z = 3.0902  # the standard normal's 1 - SIGNIFICANCE quantile
# A unit whose own data reject its shrunk coefficients at this level keeps its own fit.
CONFLICT_LEVEL = 0.01
_CONFLICT_Z = 2.3263  # the standard normal's 1 - CONFLICT_LEVEL quantile
MIN_POOLED_UNITS = 5
_MAX_ITERATIONS = 1000
_TOLERANCE = 1e-6
# Relative singular values below this are rounding, not information.
_RCOND = 1e-12
# The MAD of a normal sample times this is its standard deviation.
_MAD_SD = 1.4826


@dataclass(frozen=True)
class DesignMoments:
    """
    Least-squares summary of one axis of a record (or of a unit's records added up).

    Columns: (T - 25) / 50 to the powers 0..MOMENT_ORDER, then dT/dt in C/s.
    ``gram`` and ``moment`` are X'X and X'y over every row, ``sum_y2`` y'y;
    per block, ``block_rows`` rows, ``block_sum_y`` the sum of y and
    ``block_sum_x`` the column sums of X; ``block_record`` numbers the record
    of each block (blocks of two records are never merged); ``rate_varies``
    whether a record's dT/dt varies after its first rate window (`RATE_VARIATION`);
    ``offsets`` the records whose own bias offset is profiled out (`own_offset`).
    """

    rows: int
    sum_y2: float
    gram: np.ndarray
    moment: np.ndarray
    block_rows: np.ndarray
    block_sum_y: np.ndarray
    block_sum_x: np.ndarray
    block_s: float
    block_record: np.ndarray
    temperature_min_c: float
    temperature_max_c: float
    rate_varies: bool
    offsets: int = 0

    def own_offset(self) -> 'DesignMoments':
        """
        Give these moments with a bias offset of the record's own profiled out.

        An indicator column d of the record's rows beside X leaves, for the
        other coefficients, the normal equations of the rows about their
        means: X'X - s s' / n and X'y - s sum(y) / n (s = X'1, the first row
        of X'X, whose column 0 is 1), y'y - sum(y)^2 / n; each block's sums
        less its rows times the record's means.
        """
        rows = self.gram[0, 0]
        if not rows > 0.0:
            return self
        column_mean = self.gram[0] / rows
        mean_y = self.moment[0] / rows
        return replace(
            self, gram=self.gram - rows * np.outer(column_mean, column_mean),
            moment=self.moment - column_mean * self.moment[0],
            sum_y2=float(self.sum_y2 - mean_y * self.moment[0]),
            block_sum_y=self.block_sum_y - self.block_rows * mean_y,
            block_sum_x=self.block_sum_x - np.outer(self.block_rows, column_mean),
            offsets=self.offsets + 1)

    def __add__(self, other: 'DesignMoments') -> 'DesignMoments':
        return DesignMoments(
            rows=self.rows + other.rows, sum_y2=self.sum_y2 + other.sum_y2,
            gram=self.gram + other.gram, moment=self.moment + other.moment,
            block_rows=np.concatenate([self.block_rows, other.block_rows]),
            block_sum_y=np.concatenate([self.block_sum_y, other.block_sum_y]),
            block_sum_x=np.concatenate([self.block_sum_x, other.block_sum_x]),
            block_s=max(self.block_s, other.block_s),
            block_record=np.concatenate([self.block_record,
                                         other.block_record + self.block_record.max() + 1]),
            temperature_min_c=min(self.temperature_min_c, other.temperature_min_c),
            temperature_max_c=max(self.temperature_max_c, other.temperature_max_c),
            rate_varies=self.rate_varies or other.rate_varies,
            offsets=self.offsets + other.offsets)


def unit_moments(records) -> 'DesignMoments':
    """
    Give the moments of a unit's records (DesignMoments of one axis, in order).

    Each record but the last has its own bias offset profiled out
    (`DesignMoments.own_offset`): the constant of a fit is the last record's,
    the one the robot runs on after it, as ``diagnose`` writes it.
    """
    records = list(records)
    if not records:
        raise CalibrationError('design moments: a unit needs a record')
    total = records[-1]
    for record in reversed(records[:-1]):
        total = record.own_offset() + total
    return total


def record_moments(time_s, temperature_c, rate_rad_s, axes) -> dict:
    """
    Summarise a record for pooling, as a JSON-ready document (`moments_of` reads it).

    ``rate_rad_s`` (samples, axes) is what the bias is fitted to (the gyro rate
    at rest, or minus a reference rate), rows in time order; the columns are
    shared by the axes, stored once.
    """
    time = np.asarray(time_s, dtype=float)
    temperature = np.asarray(temperature_c, dtype=float)
    rate = np.asarray(rate_rad_s, dtype=float).reshape(len(time), -1)
    if time.size < 2 or rate.shape[1] != len(axes) or not (
            np.all(np.isfinite(time)) and np.all(np.isfinite(temperature))
            and np.all(np.isfinite(rate))):
        raise CalibrationError('design moments need 2 rows or more of finite numbers, one '
                               'rate column per axis')
    x = (temperature - MOMENT_REFERENCE_C) / MOMENT_SCALE_C
    slope = TemperatureSlope(RATE_WINDOW_S).batch(time, temperature)
    columns = np.column_stack([x[:, None] ** np.arange(MOMENT_ORDER + 1), slope])
    # The slope builds up from 0 over the first window (the node's start): not a test of c.
    settled = slope[time >= time[0] + RATE_WINDOW_S]
    rms = math.sqrt(float(np.mean(settled ** 2))) if settled.size > 2 else 0.0
    block_s = max(BLOCK_S, (time[-1] - time[0]) / MAX_BLOCKS)
    block = np.minimum(((time - time[0]) / block_s).astype(int), MAX_BLOCKS - 1)
    count = int(block.max()) + 1
    return {
        'rows': int(time.size), 'block_s': float(block_s),
        'temperature_min_c': float(temperature.min()),
        'temperature_max_c': float(temperature.max()),
        'rate_varies': bool(rms > 0.0 and float(np.std(settled)) >= RATE_VARIATION * rms),
        'gram': (columns.T @ columns).tolist(),
        'block_rows': np.bincount(block, minlength=count).tolist(),
        'block_sum_x': np.column_stack([np.bincount(block, column, count)
                                        for column in columns.T]).tolist(),
        'axes': {str(axis): {'sum_y2': float(y @ y), 'moment': (columns.T @ y).tolist(),
                             'block_sum_y': np.bincount(block, y, count).tolist()}
                 for axis, y in zip(axes, rate.T)},
    }


def moments_of(document: dict) -> dict:
    """Give {axis: DesignMoments} of a `record_moments` document; CalibrationError if bad."""
    columns = MOMENT_ORDER + 2
    try:
        shared = {
            'rows': int(document['rows']), 'block_s': float(document['block_s']),
            'temperature_min_c': float(document['temperature_min_c']),
            'temperature_max_c': float(document['temperature_max_c']),
            'rate_varies': bool(document['rate_varies']),
            'gram': np.asarray(document['gram'], dtype=float).reshape(columns, columns),
            'block_rows': np.asarray(document['block_rows'], dtype=float),
            'block_sum_x': np.asarray(document['block_sum_x'],
                                      dtype=float).reshape(-1, columns)}
        shared['block_record'] = np.zeros(shared['block_rows'].size, dtype=int)
        found = {axis: DesignMoments(
            sum_y2=float(values['sum_y2']),
            moment=np.asarray(values['moment'], dtype=float).reshape(columns),
            block_sum_y=np.asarray(values['block_sum_y'], dtype=float), **shared)
            for axis, values in document['axes'].items()}
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        msg = f'design moments: {type(err).__name__}: {err}'
        raise CalibrationError(msg) from None
    for moments in found.values():
        if not moments.block_rows.size == moments.block_sum_y.size == \
                moments.block_sum_x.shape[0]:
            raise CalibrationError('design moments: block fields differ in length')
    return found


@dataclass(frozen=True)
class PoolingDesign:
    """
    The coefficients every unit of a fleet is fitted with, on one axis.

    Bias polynomial of ``order`` in x = (T - reference_c) / scale_c, lowest
    order first, then (``rate``) the temperature-rate coefficient in
    rad/s per C/s.
    """

    order: int
    reference_c: float
    scale_c: float
    rate: bool = True

    def __post_init__(self) -> None:
        if not 0 <= self.order <= MOMENT_ORDER:
            msg = f'pooling order must be 0 to {MOMENT_ORDER}, got {self.order}'
            raise CalibrationError(msg)
        if not (math.isfinite(self.reference_c) and self.scale_c > 0.0):
            msg = f'pooling reference {self.reference_c} and scale {self.scale_c} are invalid'
            raise CalibrationError(msg)

    @property
    def size(self) -> int:
        return self.order + 1 + int(self.rate)

    @property
    def names(self) -> tuple:
        return tuple(f'bias[{k}]' for k in range(self.order + 1)) + \
            (('temperature_rate_rad_s_per_c_s',) if self.rate else ())

    def transform(self) -> np.ndarray:
        """
        Give M with X_design = X_moments M.

        x = a x0 + b (a = 50 / scale, b = (25 - reference) / scale), so
        x^j = sum over k of C(j, k) a^k b^(j - k) x0^k.
        """
        a = MOMENT_SCALE_C / self.scale_c
        b = (MOMENT_REFERENCE_C - self.reference_c) / self.scale_c
        matrix = np.zeros((MOMENT_ORDER + 2, self.size))
        for j in range(self.order + 1):
            for k in range(j + 1):
                matrix[k, j] = math.comb(j, k) * a ** k * b ** (j - k)
        if self.rate:
            matrix[-1, -1] = 1.0
        return matrix

    def bias_and_rate(self, coefficients) -> tuple:
        """Split coefficients into (bias polynomial, temperature-rate coefficient or 0)."""
        coefficients = [float(c) for c in coefficients]
        return coefficients[:self.order + 1], coefficients[-1] if self.rate else 0.0


def _solve(gram: np.ndarray, moment: np.ndarray) -> tuple:
    """Least squares from normal equations, scaled to a unit diagonal; (solution, rank)."""
    diagonal = np.diag(gram)
    scale = np.sqrt(np.where(diagonal > 0.0, diagonal, 1.0))
    solution, _, rank, _ = np.linalg.lstsq(gram / np.outer(scale, scale), moment / scale,
                                           rcond=_RCOND)
    return solution / scale, int(rank)


@dataclass(frozen=True)
class UnitData:
    """One unit's normal equations in a `PoolingDesign`, its own fit and residual figures."""

    gram: np.ndarray
    moment: np.ndarray
    coefficients: np.ndarray
    rank: int
    residual: float
    sigma2: float
    # Rows and residual sums of stretches of about KAPPA_STRETCH_S, for kappa.
    stretch_rows: np.ndarray
    stretch_residual: np.ndarray
    # Records' own offsets profiled out: each leaves its stretches summing to zero.
    offsets: int = 0


def unit_data(moments: DesignMoments, design: PoolingDesign) -> UnitData:
    """Give a unit's own least-squares fit in ``design``; sigma^2 nan without residual dof."""
    matrix = design.transform()
    gram = matrix.T @ moments.gram @ matrix
    moment = matrix.T @ moments.moment
    coefficients, rank = _solve(gram, moment)
    residual = max(moments.sum_y2 - float(coefficients @ moment), 0.0)
    dof = moments.rows - rank - moments.offsets
    per = max(1, int(round(KAPPA_STRETCH_S / moments.block_s)))
    _, stretch = np.unique(moments.block_record * (moments.block_rows.size + 1)
                           + np.arange(moments.block_rows.size) // per, return_inverse=True)
    rows = np.bincount(stretch, moments.block_rows)
    sums = np.bincount(stretch, moments.block_sum_y) - \
        np.bincount(stretch, moments.block_sum_x @ matrix @ coefficients)
    kept = rows > 0
    return UnitData(gram=gram, moment=moment, coefficients=coefficients, rank=rank,
                    residual=residual, sigma2=residual / dof if dof > 0 else math.nan,
                    stretch_rows=rows[kept], stretch_residual=sums[kept],
                    offsets=moments.offsets)


def fleet_kappa(units, size: int) -> tuple:
    """
    Give (kappa, degrees of freedom) over ``units`` (UnitData) of a design of ``size``.

    White noise gives a stretch's residual sum a variance of rows x sigma^2;
    kappa is what the stretches show over that, pooled over the units with
    more stretches than coefficients and profiled offsets; at least 1, and 1
    with no such unit.
    """
    observed = expected = 0.0
    dof = 0
    for unit in units:
        free = unit.stretch_rows.size - size - unit.offsets
        if free <= 0 or not unit.sigma2 > 0.0:
            continue
        observed += float(np.sum(unit.stretch_residual ** 2 / unit.stretch_rows))
        expected += free * unit.sigma2
        dof += free
    return (max(1.0, observed / expected), dof) if dof else (1.0, 0)


@dataclass(frozen=True)
class ColumnTest:
    """Whether the units jointly show a column: sum of its chi^2 over them, against chi^2(dof)."""

    column: str
    statistic: float
    dof: int
    threshold: float

    @property
    def significant(self) -> bool:
        return self.dof > 0 and self.statistic > self.threshold


def _chi2_quantile(dof: int, normal_quantile: float = _SIGNIFICANCE_Z) -> float:
    """Give chi^2's quantile with ``dof`` at the standard normal's (Wilson and Hilferty)."""
    third = 2.0 / (9.0 * dof)
    return dof * (1.0 - third + normal_quantile * math.sqrt(third)) ** 3


def _column_test(column: str, moments: list, wide: PoolingDesign, narrow: PoolingDesign,
                 variances: list) -> ColumnTest:
    """Test what ``wide`` adds to ``narrow`` over the units (variances: kappa sigma^2 each)."""
    statistic, dof = 0.0, 0
    for unit, variance in zip(moments, variances):
        if not variance > 0.0:
            continue
        with_column, without = unit_data(unit, wide), unit_data(unit, narrow)
        if with_column.rank > without.rank:
            statistic += max(without.residual - with_column.residual, 0.0) / variance
            dof += with_column.rank - without.rank
    return ColumnTest(column, statistic, dof, _chi2_quantile(dof) if dof else math.inf)


def choose_design(moments, reference_c: float, scale_c: float) -> tuple:
    """
    Give the fleet's (PoolingDesign, the ColumnTests that chose it) from units' moments.

    The order is the highest of MOMENT_ORDER..1 (else 0) whose top power the
    units show jointly: the sum over units of the residual reduction it
    brings, each in its unit's kappa sigma^2 of the widest design, against
    chi^2 with a degree per unit at 1 - SIGNIFICANCE. Then the temperature
    rate at that order, the same way over the units whose records vary dT/dt
    (on a single ramp c x dT/dt is one more constant, found only in the first
    rate window, and would be extrapolated to every other rate); when the
    units do not show it, it is dropped and the order chosen again without it.
    """
    moments = list(moments)
    widest = PoolingDesign(MOMENT_ORDER, reference_c, scale_c)
    data = [unit_data(unit, widest) for unit in moments]
    kappa, _ = fleet_kappa(data, widest.size)
    variances = [kappa * unit.sigma2 for unit in data]
    tests = []

    def order(rate: bool) -> int:
        for top in range(MOMENT_ORDER, 0, -1):
            test = _column_test(f'bias[{top}]' + (' beside the rate' if rate else ''), moments,
                                PoolingDesign(top, reference_c, scale_c, rate),
                                PoolingDesign(top - 1, reference_c, scale_c, rate), variances)
            tests.append(test)
            if test.significant:
                return top
        return 0

    top = order(True)
    varied = [(unit, variance) for unit, variance in zip(moments, variances)
              if unit.rate_varies]
    rate = _column_test('temperature_rate_rad_s_per_c_s', [unit for unit, _ in varied],
                        PoolingDesign(top, reference_c, scale_c, True),
                        PoolingDesign(top, reference_c, scale_c, False),
                        [variance for _, variance in varied])
    tests.append(rate)
    if not rate.significant:
        top = order(False)
    return PoolingDesign(top, reference_c, scale_c, rate.significant), tuple(tests)


def information(unit: UnitData, sigma2: float, kappa: float) -> tuple:
    """Give (J, h) = (X'X, X'y) / (kappa sigma^2) of a unit; ``sigma2`` where it has none."""
    variance = kappa * (unit.sigma2 if unit.sigma2 > 0.0 else sigma2)
    return unit.gram / variance, unit.moment / variance


@dataclass(frozen=True)
class Population:
    """The fleet's coefficient distribution: mean, between-unit covariance, how EM ended."""

    mean: np.ndarray
    covariance: np.ndarray
    units: int
    iterations: int
    converged: bool


class _Units:
    """The units' (J_i, h_i) stacked, and their own fits J_i^+ h_i."""

    def __init__(self, informations: list):
        self.infos = np.array([info for info, _ in informations])
        self.vectors = np.array([vector for _, vector in informations])
        self.own = np.array([_solve(info, vector)[0] for info, vector in informations])

    def posteriors(self, covariance: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Give P_i = (I + Sigma J_i / w_i)^-1 Sigma / w_i, the posterior covariances."""
        prior = covariance[None] / weights[:, None, None]
        posterior = np.linalg.solve(np.eye(covariance.shape[0]) + prior @ self.infos, prior)
        return 0.5 * (posterior + np.swapaxes(posterior, 1, 2))

    def weights(self, mean: np.ndarray, covariance: np.ndarray) -> np.ndarray:
        """
        Give each unit's t weight (nu + p) / (nu + d^2) at (mu, Sigma).

        d^2 = (b_i - mu)' (Sigma + J_i^-1)^-1 (b_i - mu), the unit's own fit
        against the fleet given its own uncertainty, is u' J^+ u - u' P u with
        u = h - J mu and P = (I + Sigma J)^-1 Sigma (Woodbury): no inverse of
        a J that a short record leaves singular.
        """
        residual = self.vectors - self.infos @ mean
        posterior = self.posteriors(covariance, np.ones(len(residual)))
        distance = np.einsum('ni,ni->n', self.own - mean, residual) - \
            np.einsum('ni,nij,nj->n', residual, posterior, residual)
        return (T_DEGREES_OF_FREEDOM + mean.size) / \
            (T_DEGREES_OF_FREEDOM + np.maximum(distance, 0.0))

    def em_step(self, mean: np.ndarray, covariance: np.ndarray) -> tuple:
        """One EM step: the units' posteriors under N(mu, Sigma / w_i), then (mu, Sigma)."""
        weights = self.weights(mean, covariance)
        posterior = self.posteriors(covariance, weights)
        means = mean + np.einsum('nij,nj->ni', posterior, self.vectors - self.infos @ mean)
        new_mean = weights @ means / weights.sum()
        centred = means - new_mean
        new_cov = (np.einsum('n,ni,nj->ij', weights, centred, centred)
                   + np.einsum('n,nij->ij', weights, posterior)) / len(weights)
        return new_mean, 0.5 * (new_cov + new_cov.T)


def _unpack(theta: np.ndarray, size: int) -> tuple:
    covariance = theta[size:].reshape(size, size)
    return theta[:size], 0.5 * (covariance + covariance.T)


def _positive_definite(theta: np.ndarray, size: int) -> bool:
    try:
        np.linalg.cholesky(_unpack(theta, size)[1])
    except np.linalg.LinAlgError:
        return False
    return True


def fit_population(informations) -> Population:
    """
    Estimate the population mean and between-unit covariance from units' (J, h).

    EM (`_Units.em_step`) accelerated by SQUAREM (Varadhan and Roland 2008,
    scheme 3; an extrapolation that leaves Sigma not positive definite falls
    back to the plain EM step). It starts where outliers cannot pull it: mu
    the median of the units' own fits, Sigma diagonal, their MAD (as a
    standard deviation) or what the average unit cannot resolve, the larger. The Sigma given is
    EM's plus its floor (the comment at the end).
    """
    informations = list(informations)
    if len(informations) < MIN_POOLED_UNITS:
        msg = f'a population needs at least {MIN_POOLED_UNITS} units, got {len(informations)}'
        raise CalibrationError(msg)
    units = _Units(informations)
    size = units.vectors.shape[1]
    mean = np.median(units.own, axis=0)
    spread = (_MAD_SD * np.median(np.abs(units.own - mean), axis=0)) ** 2
    unresolved = np.abs(np.diag(np.linalg.pinv(units.infos.mean(axis=0), rcond=_RCOND)))
    covariance = np.diag(np.maximum(spread, unresolved))
    theta = np.concatenate([mean, covariance.ravel()])

    def step(theta: np.ndarray) -> np.ndarray:
        return np.concatenate([part.ravel() for part in units.em_step(*_unpack(theta, size))])

    converged = False
    iteration = 0
    for iteration in range(1, _MAX_ITERATIONS + 1):
        first = step(theta)
        second = step(first)
        r = first - theta
        v = second - first - r
        alpha = max(1.0, np.linalg.norm(r) / max(np.linalg.norm(v), np.finfo(float).tiny))
        proposal = theta + 2.0 * alpha * r + alpha ** 2 * v
        new = step(proposal if _positive_definite(proposal, size) else second)
        if not _positive_definite(new, size):
            new = second
        sigma = np.sqrt(np.diag(_unpack(new, size)[1]))
        change = np.abs(new - theta) / np.concatenate([sigma, np.outer(sigma, sigma).ravel()])
        theta = new
        if float(np.max(change)) < _TOLERANCE:
            converged = True
            break
    mean, covariance = _unpack(theta, size)
    # Units that agree within their noise drive EM's Sigma toward singular; along such a
    # direction the fleet cannot tell a spread below the standard error of a variance
    # estimate at zero, sqrt(2 / N) x the average unit's estimation covariance.
    floor = math.sqrt(2.0 / len(informations)) * \
        np.linalg.pinv(units.infos.mean(axis=0), rcond=_RCOND, hermitian=True)
    return Population(mean=mean, covariance=covariance + floor, units=len(informations),
                      iterations=iteration, converged=converged)


@dataclass(frozen=True)
class ConflictTest:
    """A unit's own data against its shrunk coefficients: q, chi^2(dof) at CONFLICT_LEVEL."""

    statistic: float
    dof: int
    threshold: float

    @property
    def rejected(self) -> bool:
        return self.dof > 0 and self.statistic > self.threshold


@dataclass(frozen=True)
class Shrunk:
    """
    A unit's coefficients shrunk toward the population, or its own where its data refuse them.

    ``conflict`` tests the posterior mean on the unit's own data (module
    docstring); when it rejects it, the coefficients are the own fit's and the
    fleet's share is 0.
    """

    coefficients: np.ndarray
    weight: float
    # tr((Sigma / w)^-1 P) / p = tr((I + J Sigma / w)^-1) / p: 1 all the fleet's, 0 all its own.
    prior_share: float
    conflict: ConflictTest


def shrink(population: Population, info: np.ndarray, vector: np.ndarray) -> Shrunk:
    """
    Give a unit's posterior under the population, or its own fit where its data reject that.

    A unit far from the fleet moves little (its t weight); one whose record
    rejects its posterior mean (`ConflictTest`) keeps its own fit.
    """
    units = _Units([(info, vector)])
    weight = units.weights(population.mean, population.covariance)
    posterior = units.posteriors(population.covariance, weight)[0]
    size = population.mean.size
    share = np.trace(np.linalg.inv(np.eye(size) + info @ population.covariance / weight[0]))
    coefficients = population.mean + posterior @ (vector - info @ population.mean)
    own, rank = _solve(info, vector)
    moved = coefficients - own
    conflict = ConflictTest(statistic=max(float(moved @ info @ moved), 0.0), dof=rank,
                            threshold=_chi2_quantile(rank, _CONFLICT_Z) if rank else math.inf)
    if conflict.rejected:
        coefficients, share = own, 0.0
    return Shrunk(coefficients=coefficients, weight=float(weight[0]),
                  prior_share=float(share / size), conflict=conflict)


@dataclass(frozen=True)
class UnitPooling:
    """One unit's own fit in the fleet design, its shrunk fit, and how much the fleet moved it."""

    own: np.ndarray
    shrunk: np.ndarray
    weight: float
    prior_share: float
    pooled: bool
    conflict: ConflictTest


@dataclass(frozen=True)
class FleetPooling:
    """One axis of a fleet: design, noise figures, population, every unit's fits."""

    design: PoolingDesign
    tests: tuple
    kappa: float
    kappa_dof: int
    sigma2_median: float
    population: Population
    units: dict


def pool_fleet(moments: dict, pooled, reference_c: float, scale_c: float) -> FleetPooling:
    """
    Pool one axis of a fleet, ``moments`` {unit: DesignMoments}.

    The population is estimated from the units in ``pooled``; the others
    (outliers) are only shrunk. The design by `choose_design` in
    x = (T - reference_c) / scale_c, kappa by `fleet_kappa`; a unit whose
    record leaves no residual degree of freedom takes the median sigma^2 of
    the pooled units.
    """
    chosen = set(pooled)
    pooled = [unit for unit in moments if unit in chosen]
    if len(pooled) < MIN_POOLED_UNITS:
        msg = f'a population needs at least {MIN_POOLED_UNITS} units, got {len(pooled)}'
        raise CalibrationError(msg)
    design, tests = choose_design([moments[unit] for unit in pooled], reference_c, scale_c)
    data = {unit: unit_data(found, design) for unit, found in moments.items()}
    kappa, kappa_dof = fleet_kappa([data[unit] for unit in pooled], design.size)
    variances = [data[unit].sigma2 for unit in pooled if data[unit].sigma2 > 0.0]
    if not variances:
        raise CalibrationError('no pooled unit has more rows than coefficients')
    sigma2 = float(np.median(variances))
    informations = {unit: information(found, sigma2, kappa) for unit, found in data.items()}
    population = fit_population([informations[unit] for unit in pooled])
    units = {}
    for unit, found in data.items():
        shrunk = shrink(population, *informations[unit])
        units[unit] = UnitPooling(own=found.coefficients, shrunk=shrunk.coefficients,
                                  weight=shrunk.weight, prior_share=shrunk.prior_share,
                                  pooled=unit in chosen, conflict=shrunk.conflict)
    return FleetPooling(design=design, tests=tests, kappa=kappa, kappa_dof=kappa_dof,
                        sigma2_median=sigma2, population=population, units=units)
