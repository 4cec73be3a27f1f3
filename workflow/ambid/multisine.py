"""Periodic random-phase multisine identification (Pintelon & Schoukens 2012, ch. 2-4), batched on the rig.

Beyond the thesis' stepped sine (ch. 4.2): one excitation holds every frequency
line at once, so the whole band is measured in a few seconds instead of one
step after another.  The signal of an axis is

    E_u(t) = sum_k a_k cos(2 pi k f0 t + phi_k)          (k in the excited harmonics)

periodic with period ``1 / f0``.  Its design follows Pintelon & Schoukens
(*System Identification: A Frequency Domain Approach*, 2nd ed., 2012):

* **Odd random harmonic grid** (sec. 4.2.7): only odd harmonics of ``f0`` are
  excited, and of every ``detection_group`` consecutive odd candidates one,
  drawn at random, is left out.  Even nonlinear distortion then falls on the
  even harmonics, odd distortion also on the left-out odd ones: these
  *detection lines* show both kinds separately (`ambid.bla.distortion_levels`).
  Above ``2 / relative_spacing`` harmonics the candidates thin out to a
  quasi-logarithmic grid (relative spacing at least ``relative_spacing``), so
  the power is not spent on ever denser high-frequency lines.
* **Random phases** ``phi_k`` uniform in [0, 2 pi), new in each of R
  realizations: the best linear approximation (BLA) and its nonlinear
  distortion are averages and variances over the realizations (sec. 3.4).
* **P periods** of each realization after a settling time: the scatter between
  the periods is the noise (sec. 2.5).  The realizations cycle through relative
  rms ``levels`` (default 1 and 0.5): the BLA's change with the level is the
  deterministic part of the nonlinear error (`ambid.bla`).
* **Orthogonal multisines** (sec. 3.7, Dobrowiecki et al. 2006): the radial
  axes are excited together, in experiment ``e`` with the signs ``T[e, i]``
  of a Hadamard matrix (a DFT matrix for group sizes without one), so ``E``
  experiments give the full MIMO plant ``P = V U^-1`` with every axis excited
  in every experiment.  The axial axis has its own lines (in its band, every
  other excited line of the radial grid) and is excited in every experiment;
  ``per_axis`` instead excites one axis per experiment, as the stepped sine does.
* **Amplitude spectrum shaped to the plant**: ``a_k ~ |C_aa(f_k)|^-alpha`` with
  the nominal model's dynamic compliance ``C`` (E_u -> V2, thesis Table 4.1,
  smoothed over +-10 % in frequency: the model's resonances are what is
  uncertain), more power where the compliance is low, as the stepped sine
  plans its amplitudes.  ``alpha = 1/2`` minimizes the sum of the lines'
  relative FRF variances for a given power; ``alpha = 1`` is the stepped
  sine's flat response.  The first level is the largest at which no axis'
  excitation peak exceeds its limit (a fraction of its bias current, at most
  ``amplitude_max_a``) and the predicted position peak ``response_max_m``;
  a *level check* then plays one period of the first experiment and sets the
  level from the measured response, as the stepped sine adapts its amplitude
  (a model's resonance in the wrong place cannot overdrive the machine).
* **Zoom** (`identify_multisine`): the coarse pass is fitted, and a second
  pass excites only narrow bands around the resonances and anti-resonances
  the fit found (`ambid.zoom`), shaped and levelled with the coarse pass'
  measured compliance.
* **Crest factor** ``max |x| / rms(x)`` reduced by iterative clipping with
  amplitude restoration (Van der Ouderaa, Schoukens & Renneboog 1988) from
  the random start, which keeps the phases of different realizations random.

Every realization and experiment is an independent experiment on the machine
at rest, so all of them run as one batch through the rig, in lockstep.  Their
machine time, as on a real machine where they run one after another, is
``R E (settle + P / f0)`` plus the level check.
"""

from dataclasses import dataclass, field, replace

import numpy as np

from .errors import ConfigError, settings_from_mapping
from .excitation import amplitude_limits
from .loop import axial_transfer_functions, transfer_functions
from .machine import ALL_AXES, AXIAL_AXIS, RADIAL_AXES

__all__ = ["MultisineSettings", "multisine_settings_from_config", "ORTHOGONAL", "PER_AXIS", "harmonic_grid",
           "orthogonal_matrix", "reduce_crest_factor", "crest_factor", "MultisineDesign", "design_multisine",
           "zoom_design", "nominal_compliance", "run_multisine", "period_spectra", "pass_record", "measured_compliance",
           "identify_multisine"]

ORTHOGONAL, PER_AXIS = "orthogonal", "per_axis"


@dataclass(frozen=True)
class MultisineSettings:
    """Settings of a multisine identification run (config section ``multisine``).

    Attributes
    ----------
    design : {"orthogonal", "per_axis"}
        All radial axes at once with orthogonal signs, or one axis per experiment.
    axes : tuple of str
        Axes excited.
    frequency_resolution_hz : float
        ``f0``, the line spacing; the period is ``1 / f0`` rounded to whole controller cycles.
    radial_band_hz, axial_band_hz : (float, float)
        Excited band of the radial axes and of Z.
    relative_spacing : float
        Smallest relative spacing of excited candidates above the linear part of the grid (0: linear throughout).
    detection_group : int
        One odd candidate of every this many is left out as a detection line (0: none left out).
    periods, realizations : int
        P (>= 2: the noise) and R (>= 2: the nonlinear distortion) of the coarse pass.
    levels : tuple of float
        Relative rms levels the realizations cycle through (first 1).  A BLA depends
        on the excitation's level; a second level measures how much
        (`ambid.bla`): the part of the nonlinear error the scatter of same-level
        realizations cannot show (sec. 3.5).
    settle_s : float
        Settling before the first recorded period of every experiment.
    amplitude_max_a : float
        Largest peak of an axis' excitation [A] (the machine's limit, as the stepped sine's).
    coarse_bias_fraction, zoom_bias_fraction : float
        Largest peak of an axis' excitation relative to its bias current, in the
        coarse and the zoom pass (below ``amplitude_max_a``).  The force law's
        nonlinearity grows with ``i / i_bias`` (its position stiffness with the
        mean-square current), and a BLA is biased by the rms current of *all*
        lines (sec. 3.4: the BLA depends on the excitation's power spectrum),
        most at low frequencies where the bearing stiffness matters: the coarse
        pass stays lower; the zoom's lines sit at the flexible modes.
    response_max_m : float
        Largest peak of an axis' position response, as the nominal model predicts it
        (and as the level check measures it).
    shaping_exponent : float
        ``alpha`` of the amplitude spectrum ``|C|^-alpha``.
    crest_iterations : int
        Clipping iterations of the crest-factor reduction (0: random phases as drawn).
    level_check : bool
        Play one period of the first realization first and lower the level where the response exceeds the plan.
    zoom : bool
        After the coarse pass, a dense pass around every resonance and anti-resonance its fit found.
    zoom_lines_per_bandwidth : float
        Zoom line spacing: the narrowest fitted half-power bandwidth ``2 zeta f`` holds this many lines.
    zoom_lines_per_band : int
        A wider band (a higher mode) holds about this many lines (every m-th harmonic).
    zoom_width : float
        Half width of a zoom band in half-power bandwidths (``zeta f``), at least ``zoom_min_width`` relative.
    zoom_min_width : float
    zoom_damping_max : float
        Features damped more than this are not zoomed (the coarse pass resolves them).
    zoom_resolution_min_hz : float
        Finest zoom line spacing (longest period).
    zoom_periods, zoom_realizations : int
    zoom_levels : tuple of float
    zoom_shaping_exponent : float
        ``alpha`` of the zoom pass, on the measured compliance (0: the same current on every zoom line).
    zoom_settle_decays : float
        Zoom settling: at least this many decay times ``1 / (2 pi zeta f)`` of the
        slowest fitted mode (and ``settle_s``).
    """

    design: str = ORTHOGONAL
    axes: tuple = ALL_AXES
    frequency_resolution_hz: float = 1.25
    radial_band_hz: tuple = (1.0, 3000.0)
    axial_band_hz: tuple = (1.0, 100.0)
    relative_spacing: float = 0.005
    detection_group: int = 4
    periods: int = 2
    realizations: int = 2
    levels: tuple = (1.0, 0.5)
    settle_s: float = 0.5
    amplitude_max_a: float = 3.0
    coarse_bias_fraction: float = 0.3
    zoom_bias_fraction: float = 0.6
    response_max_m: float = 50e-6
    shaping_exponent: float = 0.5
    crest_iterations: int = 40
    level_check: bool = True
    zoom: bool = True
    zoom_lines_per_bandwidth: float = 2.0
    zoom_lines_per_band: int = 15
    zoom_width: float = 4.0
    zoom_min_width: float = 0.01
    zoom_damping_max: float = 0.05
    zoom_resolution_min_hz: float = 0.25
    zoom_periods: int = 2
    zoom_realizations: int = 2
    zoom_levels: tuple = (1.0, 0.5)
    zoom_shaping_exponent: float = 0.0
    zoom_settle_decays: float = 4.0

    def __post_init__(self):
        def band_ok(band):
            return len(band) == 2 and 0 < band[0] < band[1]

        checks = [
            ("design", self.design in (ORTHOGONAL, PER_AXIS), f"must be {ORTHOGONAL!r} or {PER_AXIS!r}"),
            ("frequency_resolution_hz", self.frequency_resolution_hz > 0, "must be > 0"),
            ("radial_band_hz", band_ok(self.radial_band_hz), "must be [low, high] with 0 < low < high"),
            ("axial_band_hz", band_ok(self.axial_band_hz), "must be [low, high] with 0 < low < high"),
            ("relative_spacing", 0 <= self.relative_spacing < 1, "must lie in [0, 1)"),
            ("detection_group", self.detection_group == 0 or self.detection_group >= 2, "must be 0 or >= 2"),
            ("periods", self.periods >= 2, "must be >= 2 (the noise is the scatter between periods)"),
            ("realizations", self.realizations >= 1, "must be >= 1 (>= 2 to measure the nonlinear distortion)"),
            ("settle_s", self.settle_s >= 0, "must be >= 0"),
            ("amplitude_max_a", self.amplitude_max_a > 0, "must be > 0"),
            ("coarse_bias_fraction", 0 < self.coarse_bias_fraction <= 1, "must lie in (0, 1]"),
            ("zoom_bias_fraction", 0 < self.zoom_bias_fraction <= 1, "must lie in (0, 1]"),
            ("response_max_m", self.response_max_m > 0, "must be > 0"),
            ("shaping_exponent", 0 <= self.shaping_exponent <= 1, "must lie in [0, 1]"),
            ("crest_iterations", self.crest_iterations >= 0, "must be >= 0"),
            ("zoom_lines_per_bandwidth", self.zoom_lines_per_bandwidth > 0, "must be > 0"),
            ("zoom_width", self.zoom_width > 0, "must be > 0"),
            ("zoom_min_width", 0 < self.zoom_min_width < 1, "must lie in (0, 1)"),
            ("zoom_damping_max", 0 < self.zoom_damping_max < 1, "must lie in (0, 1)"),
            ("zoom_resolution_min_hz", 0 < self.zoom_resolution_min_hz <= self.frequency_resolution_hz,
             "must lie in (0, frequency_resolution_hz]"),
            ("zoom_periods", self.zoom_periods >= 2, "must be >= 2"),
            ("zoom_realizations", self.zoom_realizations >= 1, "must be >= 1"),
            ("zoom_lines_per_band", self.zoom_lines_per_band >= 3, "must be >= 3"),
            ("zoom_settle_decays", self.zoom_settle_decays >= 0, "must be >= 0"),
            ("zoom_shaping_exponent", 0 <= self.zoom_shaping_exponent <= 1, "must lie in [0, 1]"),
        ]
        for key, ok, message in checks:
            if not ok:
                raise ConfigError(f"multisine.{key}", message)
        for key, levels, count in (("levels", self.levels, self.realizations),
                                   ("zoom_levels", self.zoom_levels, self.zoom_realizations)):
            if not levels or levels[0] != 1 or any(not 0 < v <= 1 for v in levels) or len(set(levels)) != len(levels):
                raise ConfigError(f"multisine.{key}", f"must start with 1 and hold distinct levels in (0, 1], got {list(levels)}")
            if count < len(levels):
                raise ConfigError(f"multisine.{key}", f"{len(levels)} levels need at least as many realizations ({count})")
        bad = [a for a in self.axes if a not in ALL_AXES]
        if bad or not self.axes or len(set(self.axes)) != len(self.axes):
            raise ConfigError("multisine.axes", f"must be distinct axes of {list(ALL_AXES)}, got {list(self.axes)}")


def multisine_settings_from_config(config):
    """`MultisineSettings` from the ``multisine:`` mapping (unknown keys name themselves)."""
    return settings_from_mapping(MultisineSettings, config or {}, "multisine")


# ------------------------------------------------------------------------------ the frequency grid
@dataclass(frozen=True)
class Grid:
    """Harmonic lines of one pass: the stored lines, their role, and which axes each excites.

    Attributes
    ----------
    lines : int array (L,)
        Harmonic numbers of ``f0``, ascending.
    role : str array (L,)
        One of `ambid.logs.LINE_ROLES`.
    excites : bool array (L, 5)
        Whether axis ``ALL_AXES[a]`` is excited at line ``l``.
    """

    lines: np.ndarray
    role: np.ndarray
    excites: np.ndarray


def _in_band(frequency_hz, band):
    return (frequency_hz >= band[0]) & (frequency_hz <= band[1])


def harmonic_grid(f0_hz, settings, rng, bands=None):
    """The odd random harmonic grid of a pass (Pintelon & Schoukens 2012, sec. 4.2.7).

    Parameters
    ----------
    f0_hz : float
        Line spacing (exact: ``1 / (N T)``).
    settings : MultisineSettings
    rng : numpy.random.Generator
        Draws the left-out odd lines.
    bands : dict, optional
        ``axis -> list of (low, high)`` excited bands [Hz]; default the settings'
        radial and axial bands.  Zoom passes give several narrow bands and then
        excite every harmonic in them (`zoom_design`).

    Returns
    -------
    Grid
    """
    axes = list(settings.axes)
    if bands is None:
        bands = {a: [settings.axial_band_hz if a == AXIAL_AXIS else settings.radial_band_hz] for a in axes}
    top = max(high for a in axes for _, high in bands[a])
    harmonics = np.arange(1, int(np.floor(top / f0_hz)) + 1)
    frequency = harmonics * f0_hz
    inside = np.zeros((harmonics.size, len(ALL_AXES)), dtype=bool)
    for a in axes:
        for band in bands[a]:
            inside[:, ALL_AXES.index(a)] |= _in_band(frequency, band)
    candidate = harmonics[inside.any(axis=1) & (harmonics % 2 == 1)]
    # quasi-logarithmic thinning above the linear part
    if settings.relative_spacing > 0 and candidate.size:
        kept = [candidate[0]]
        for k in candidate[1:]:
            if k - kept[-1] >= max(2, settings.relative_spacing * k):
                kept.append(k)
        candidate = np.array(kept, dtype=int)
    # random harmonic grid: one of every `detection_group` consecutive candidates is left out
    left_out = np.zeros(candidate.size, dtype=bool)
    group = settings.detection_group
    if group:
        for start in range(0, candidate.size - group + 1, group):
            left_out[start + rng.integers(group)] = True
    excited, odd = candidate[~left_out], candidate[left_out]
    excites = inside[np.searchsorted(harmonics, excited)]
    if settings.design == ORTHOGONAL:
        # radial and axial groups share no line: where both bands hold a line, they alternate
        radial = [ALL_AXES.index(a) for a in axes if a in RADIAL_AXES]
        axial = [ALL_AXES.index(a) for a in axes if a == AXIAL_AXIS]
        if radial and axial:
            both = excites[:, radial].any(axis=1) & excites[:, axial].any(axis=1)
            turn = np.cumsum(both) % 2 == 0  # every second shared line goes to the axial axis
            excites[np.ix_(both & turn, radial)] = False
            excites[np.ix_(both & ~turn, axial)] = False
    even = np.setdiff1d(np.concatenate([excited - 1, excited + 1]), np.concatenate([[0], excited, odd]))
    even = even[even % 2 == 0]
    lines = np.concatenate([excited, odd, even])
    role = np.array(["excited"] * excited.size + ["odd_detection"] * odd.size + ["even_detection"] * even.size)
    flags = np.vstack([excites, np.zeros((odd.size + even.size, len(ALL_AXES)), dtype=bool)])
    order = np.argsort(lines, kind="stable")
    return Grid(lines[order], role[order], flags[order])


def orthogonal_matrix(size):
    """``size x size`` matrix with orthogonal columns of unit-modulus entries (sec. 3.7).

    A Hadamard matrix (entries +-1: a sign flip leaves a signal's crest factor
    unchanged) when ``size`` is a power of two, else the DFT matrix.
    """
    if size & (size - 1) == 0:
        matrix = np.ones((1, 1))
        while matrix.shape[0] < size:
            matrix = np.block([[matrix, matrix], [matrix, -matrix]])
        return matrix.astype(complex)
    k = np.arange(size)
    return np.exp(2j * np.pi * np.outer(k, k) / size)


# ------------------------------------------------------------------------------ crest factor
def crest_factor(signal):
    """``max |x| / rms(x)`` of a signal (sqrt 2 for one sine)."""
    signal = np.asarray(signal, dtype=float)
    return float(np.max(np.abs(signal)) / np.sqrt(np.mean(signal**2)))


def _waveform(amplitudes, phases, lines, n_samples):
    """One period of ``sum a_k cos(2 pi k n / N + phi_k)``, ``N = n_samples``."""
    spectrum = np.zeros(n_samples // 2 + 1, dtype=complex)
    spectrum[lines] = 0.5 * n_samples * amplitudes * np.exp(1j * phases)
    return np.fft.irfft(spectrum, n_samples)


def reduce_crest_factor(amplitudes, phases, lines, n_samples, iterations, clip_rms=1.3):
    """Iterative clipping with amplitude restoration (Van der Ouderaa, Schoukens & Renneboog 1988).

    Each iteration clips the period at ``clip_rms`` times its rms, keeps the
    phases of the clipped signal at the excited lines and restores their
    amplitudes; the phases of the lowest crest factor seen are kept.  From a
    random start each realization ends in its own local optimum, so the
    phases stay random across realizations.  Typically 3.3 -> 1.8-1.9 in 40
    iterations.

    Returns
    -------
    phases : array
        Phases of the lowest crest factor found.
    crest : float
    """
    current = np.asarray(phases, dtype=float)
    best_phases, best = current, crest_factor(_waveform(amplitudes, current, lines, n_samples))
    for _ in range(iterations):
        signal = _waveform(amplitudes, current, lines, n_samples)
        level = clip_rms * np.sqrt(np.mean(signal**2))
        current = np.angle(np.fft.rfft(np.clip(signal, -level, level))[lines])
        value = crest_factor(_waveform(amplitudes, current, lines, n_samples))
        if value < best:
            best, best_phases = value, current
    return best_phases, best


# ------------------------------------------------------------------------------ the design
@dataclass
class MultisineDesign:
    """One pass of a multisine identification: grid, reference spectra, timing.

    Attributes
    ----------
    name : str
        ``coarse`` or ``zoom``.
    sample_time_s : float
    samples_per_period : int
        ``N``; the line spacing is ``f0 = 1 / (N T)``.
    grid : Grid
    reference : complex array (R, E, 5, L)
        Complex amplitude ``a e^{j phi}`` of the excitation of each axis at each
        stored line, per realization and experiment (0 where not excited).
    periods, settle_samples : int
    crest : array (R, E, 5)
        Crest factor of each excitation signal (NaN where an axis is silent).
    amplitude_max_a : array (5,)
        The pass' peak excitation limit of each axis (the level check keeps to it).
    notes : list of str
        How the level was set (what limited it).
    """

    name: str
    sample_time_s: float
    samples_per_period: int
    grid: Grid
    reference: np.ndarray
    periods: int
    settle_samples: int
    crest: np.ndarray
    amplitude_max_a: np.ndarray = None
    notes: list = field(default_factory=list)

    @property
    def f0_hz(self):
        return 1.0 / (self.samples_per_period * self.sample_time_s)

    @property
    def frequency_hz(self):
        return self.grid.lines * self.f0_hz

    @property
    def realizations(self):
        return self.reference.shape[0]

    @property
    def experiments(self):
        return self.reference.shape[1]

    @property
    def machine_time_s(self):
        """Machine time of the pass when its experiments run one after another [s]."""
        per_experiment = self.settle_samples + self.periods * self.samples_per_period
        return self.realizations * self.experiments * per_experiment * self.sample_time_s

    def excitation_peaks(self):
        """Largest excitation peak of each axis over realizations and experiments, (5,) [A]."""
        return np.array([max((np.max(np.abs(self.waveforms(r, e)[a])) for r in range(self.realizations)
                              for e in range(self.experiments)), default=0.0) for a in range(len(ALL_AXES))])

    def crest_factors(self):
        """Crest factor of each excitation signal, (R, E, 5) (NaN where an axis is silent)."""
        out = np.full((self.realizations, self.experiments, len(ALL_AXES)), np.nan)
        for r in range(self.realizations):
            for e in range(self.experiments):
                signals = self.waveforms(r, e)
                for a in range(len(ALL_AXES)):
                    if np.any(signals[a] != 0):
                        out[r, e, a] = crest_factor(signals[a])
        return out

    def waveforms(self, realization, experiment):
        """Excitation of every axis over one period, array (5, N) [A]."""
        excited = self.grid.role == "excited"
        lines = self.grid.lines[excited]
        out = np.zeros((len(ALL_AXES), self.samples_per_period))
        for a in range(len(ALL_AXES)):
            values = self.reference[realization, experiment, a, excited]
            if np.any(values != 0):
                out[a] = _waveform(np.abs(values), np.angle(values), lines, self.samples_per_period)
        return out


def nominal_compliance(plant, frequency_hz, smoothing=0.1, points=9):
    """Magnitude of the nominal dynamic compliance E_u -> V2 (thesis Table 4.1), smoothed, array (n, 5, 5) [m/A].

    The geometric mean of ``|C|`` over ``[f / (1 + smoothing), f (1 + smoothing)]``
    (``points`` log-spaced samples): the model's resonances and anti-resonances
    are uncertain in frequency (that is why one identifies), so their sharp
    peaks and notches must not decide a line's amplitude.  The radial 4 x 4
    block and the axial element; zero elsewhere.
    """
    frequency_hz = np.asarray(frequency_hz, dtype=float)
    spread = np.geomspace(1 / (1 + smoothing), 1 + smoothing, points) if smoothing > 0 else np.ones(1)
    sampled = (frequency_hz[:, None] * spread[None, :]).ravel()
    out = np.zeros((sampled.size, len(ALL_AXES), len(ALL_AXES)))
    index = [ALL_AXES.index(a) for a in RADIAL_AXES]
    radial = np.abs(transfer_functions(plant, sampled, hold=True)["dynamic_compliance"])
    out[np.ix_(np.arange(sampled.size), index, index)] = radial
    if plant.machine.axial_electromagnet is not None:
        out[:, 4, 4] = np.abs(axial_transfer_functions(plant, sampled)["dynamic_compliance"][:, 0, 0])
    logs = np.log(np.maximum(out, 1e-300)).reshape(frequency_hz.size, spread.size, len(ALL_AXES), len(ALL_AXES))
    return np.where(out.reshape(logs.shape)[:, 0] > 0, np.exp(logs.mean(axis=1)), 0.0)


def _experiment_matrix(settings):
    """Signs ``T`` (E, 5) of each axis in each experiment."""
    axes = [ALL_AXES.index(a) for a in settings.axes]
    if settings.design == PER_AXIS:
        matrix = np.zeros((len(axes), len(ALL_AXES)), dtype=complex)
        matrix[np.arange(len(axes)), axes] = 1.0
        return matrix
    radial = [a for a in axes if ALL_AXES[a] in RADIAL_AXES]
    experiments = max(len(radial), 1)
    matrix = np.zeros((experiments, len(ALL_AXES)), dtype=complex)
    if radial:
        matrix[:, radial] = orthogonal_matrix(len(radial))
    if 4 in axes:
        matrix[:, 4] = 1.0  # the axial axis has lines of its own: excited in every experiment
    return matrix


def design_multisine(plant, settings, seed, lines_hz=None, f0_hz=None, compliance=None, name="coarse",
                     periods=None, realizations=None, bias_fraction=None, settle_s=None, levels=None):
    """Design a pass: grid, shaped amplitudes, random phases with reduced crest factor, a first level.

    Parameters
    ----------
    plant : ambid.plant.Plant
        The engineer's nominal model (the sample time; the amplitude shape and
        the first level unless ``compliance`` is given).
    settings : MultisineSettings
    seed : int
        Seed of the grid and the phases (from the run's configuration).
    lines_hz : array, optional
        Excited frequencies of a zoom pass (harmonics of ``f0_hz``, all excited on
        every axis of ``settings.axes``); default the settings' bands on the odd
        random grid (`harmonic_grid`).
    f0_hz : float, optional
        Line spacing; default ``settings.frequency_resolution_hz``.
    compliance : callable, optional
        ``frequency_hz -> (n, 5, 5)`` magnitude of the dynamic compliance to shape
        and level with (a zoom pass passes the coarse pass' measured one); default
        `nominal_compliance`.
    name : str
        ``coarse`` or ``zoom``.
    periods, realizations : int, optional
        Default the settings' coarse values.
    bias_fraction : float, optional
        Peak excitation limit relative to each axis' bias current (and at most
        ``settings.amplitude_max_a``); default ``settings.coarse_bias_fraction``.
    settle_s : float, optional
        Settling per experiment; default ``settings.settle_s``.
    levels : tuple of float, optional
        Relative levels the realizations cycle through; default ``settings.levels``.

    Returns
    -------
    MultisineDesign
        At the level where each axis' excitation peaks at its limit,
        lowered together where the position response (predicted from the
        compliance: rms of the lines times a crest factor of 3) would exceed
        ``response_max_m``.
    """
    t = plant.machine.sample_time_s
    f0 = settings.frequency_resolution_hz if f0_hz is None else f0_hz
    n_samples = int(round(1.0 / (f0 * t)))
    f0 = 1.0 / (n_samples * t)
    rng = np.random.default_rng([seed, 19, 0 if name == "coarse" else 1])
    if lines_hz is None:
        grid = harmonic_grid(f0, settings, rng)
    else:
        lines = np.unique(np.round(np.asarray(lines_hz, dtype=float) / f0).astype(int))
        excites = np.zeros((lines.size, len(ALL_AXES)), dtype=bool)
        excites[:, [ALL_AXES.index(a) for a in settings.axes]] = True
        grid = Grid(lines, np.array(["excited"] * lines.size), excites)
    excited = grid.role == "excited"
    if not excited.any():
        raise ConfigError("multisine", f"no line of {f0:.4g} Hz spacing lies in the excited bands")
    limit = amplitude_limits(plant.machine, settings,
                             settings.coarse_bias_fraction if bias_fraction is None else bias_fraction)
    if plant.machine.axial_electromagnet is None:
        limit[-1] = 0.0  # no axial bearing to excite
    frequency = grid.lines[excited] * f0
    magnitude = nominal_compliance(plant, frequency) if compliance is None else np.abs(compliance(frequency))
    diagonal = np.diagonal(magnitude, axis1=1, axis2=2)  # (n, 5)
    shape = np.where(grid.excites[excited] & (diagonal > 0), np.maximum(diagonal, 1e-300) ** -settings.shaping_exponent,
                     0.0)
    realizations = settings.realizations if realizations is None else realizations
    periods = settings.periods if periods is None else periods
    signs = _experiment_matrix(settings)
    lines = grid.lines[excited]
    phases = np.zeros((realizations, len(ALL_AXES), lines.size))
    for r in range(realizations):
        for a in range(len(ALL_AXES)):
            on = shape[:, a] > 0
            if on.any():
                start = rng.uniform(0, 2 * np.pi, on.sum())
                phases[r, a, on], _ = reduce_crest_factor(shape[on, a], start, lines[on], n_samples,
                                                          settings.crest_iterations)
    reference = np.zeros((realizations, signs.shape[0], len(ALL_AXES), grid.lines.size), dtype=complex)
    reference[:, :, :, excited] = shape.T[None, None] * np.exp(1j * phases)[:, None] * signs[None, :, :, None]
    settle = settings.settle_s if settle_s is None else settle_s
    design = MultisineDesign(name, t, n_samples, grid, reference, periods, int(np.ceil(settle / t)),
                             np.full((realizations, signs.shape[0], len(ALL_AXES)), np.nan), amplitude_max_a=limit)
    peaks = design.excitation_peaks()
    response = 3.0 * np.sqrt(0.5 * np.einsum("nab,rebn->rea", magnitude**2,
                                             np.abs(reference[:, :, :, excited]) ** 2)).max(axis=(0, 1))
    scale = np.ones(len(ALL_AXES))
    for group in ([ALL_AXES.index(a) for a in RADIAL_AXES], [ALL_AXES.index(AXIAL_AXIS)]):
        active = [a for a in group if peaks[a] > 0]
        if active:  # each axis up to the current limit, then the group together down to the response limit
            scale[active] = limit[active] / peaks[active]
            worst = max(response[a] * scale[a] / settings.response_max_m for a in active)
            scale[active] /= max(worst, 1.0)
    levels = settings.levels if levels is None else levels
    design.reference *= scale[None, None, :, None] * np.array([levels[r % len(levels)] for r in range(realizations)])[:, None, None, None]
    design.crest = design.crest_factors()
    source = "nominal model's" if compliance is None else "measured"
    design.notes.append(f"{name} pass: first level from the {source} compliance, excitation peaks "
                        + np.array2string(peaks * scale, precision=3) + " A")
    return design


def zoom_design(plant, settings, seed, lines_hz, f0_hz, compliance=None, settle_s=None):
    """The zoom pass on the radial axes: the given lines, all excited, with the whole excitation's power.

    Parameters
    ----------
    lines_hz : array
        Zoom frequencies, harmonics of ``f0_hz`` (`ambid.zoom.band_lines` times ``f0_hz``).
    f0_hz : float
        Line spacing of the pass (its period is ``1 / f0_hz``).
    compliance : callable, optional
        Measured dynamic compliance magnitude (the coarse pass) to shape and level with.
    settle_s : float, optional
        Settling per experiment (default ``settings.settle_s``; a lightly damped mode found
        by the coarse pass needs longer).
    """
    radial = tuple(a for a in settings.axes if a in RADIAL_AXES)
    zoom_settings = replace(settings, axes=radial, shaping_exponent=settings.zoom_shaping_exponent)
    return design_multisine(plant, zoom_settings, seed, lines_hz=lines_hz, f0_hz=f0_hz,
                            compliance=compliance, name="zoom", periods=settings.zoom_periods,
                            realizations=settings.zoom_realizations, bias_fraction=settings.zoom_bias_fraction,
                            settle_s=settle_s, levels=settings.zoom_levels)


# ------------------------------------------------------------------------------ the run
def period_spectra(record, lines, start_sample):
    """Fourier coefficients of one recorded period at ``lines``, phase referred to the excitation's start.

    Parameters
    ----------
    record : array (N, ...)
        One period of samples (first axis time).
    lines : int array
        Harmonics of ``1 / (N T)``.
    start_sample : int
        Cycles from the start of the excitation to the first sample of ``record``.

    Returns
    -------
    complex array (len(lines), ...)
        ``(2 / N) sum_n x_n e^{-j 2 pi k n / N}`` times ``e^{-j 2 pi k n0 / N}``:
        the complex amplitude of the line as in ``E_u`` (thesis eq. 4.2's convention).
    """
    n = record.shape[0]
    spectrum = np.fft.rfft(record, axis=0)[lines] * (2.0 / n)
    shift = np.exp(-2j * np.pi * np.asarray(lines) * (start_sample % n) / n)
    return spectrum * shift.reshape((-1,) + (1,) * (spectrum.ndim - 1))


def run_multisine(rig_model, design, seed=0, noise=True, level_check=False, response_max_m=None, margin=0.8, stream=0,
                  nonlinear=True):
    """Play a pass on the rig: every realization and experiment as one batch member.

    Parameters
    ----------
    rig_model : ambid.rig.RigModel
    design : MultisineDesign
    seed : int
        Seed of the measurement noise.
    noise : bool
        False: noise-free (tests).
    level_check : bool
        First play one period of the first experiment of realization 0 (after a
        quarter-second settle) and set the level from what was measured, as the
        stepped sine adapts its amplitude: each axis up to the pass' limit
        (``design.amplitude_max_a``), then the radial axes together (keeping the
        orthogonal design) and the axial axis each down so that the measured
        position peak would be ``margin * response_max_m``.  The design is
        scaled in place; the check's time counts as machine time.
    response_max_m : float
        Needed with ``level_check``.
    margin : float
        Share of ``response_max_m`` the check aims at (other experiments and realizations peak differently).
    stream : int
        Noise stream of the seed (each pass of a run its own).
    nonlinear : bool
        False: the rig's linearized truth (tests).

    Returns
    -------
    spectra : complex array (R, E, P, 20, L)
        Per-period Fourier coefficients of every channel (`ambid.logs.CHANNELS`
        order) at the stored lines, phases referred to the start of the excitation.
    stats : dict
        ``machine_time_s`` (the pass' experiments one after another, the level
        check included), ``level_check_s``, ``simulated_s`` (lockstep),
        ``cycles``, ``peak_response_m`` (5,) and ``peak_excitation_a`` (5,)
        over the recorded periods, ``notes``.
    """
    rng = np.random.default_rng([seed, 19, stream]) if noise else None
    stats = {"level_check_s": 0.0, "notes": list(design.notes)}
    if level_check:
        settle = min(design.settle_samples, int(round(0.25 / design.sample_time_s)))
        check = _play(rig_model, design, [(0, 0)], rng, periods=1, record=False, settle_samples=settle,
                      nonlinear=nonlinear)
        scale = _check_scale(design, check["peak_response_m"], margin * response_max_m)
        design.reference *= scale[None, None, :, None]
        design.crest = design.crest_factors()
        stats["level_check_s"] = check["simulated_s"]
        stats["notes"].append(f"{design.name} level check: position peaks "
                              + np.array2string(check["peak_response_m"] * 1e6, precision=2) + " um at excitation peaks "
                              + np.array2string(check["peak_excitation_a"], precision=3) + " A; level scaled by "
                              + np.array2string(scale, precision=3))
    members = [(r, e) for r in range(design.realizations) for e in range(design.experiments)]
    result = _play(rig_model, design, members, rng, periods=design.periods, record=True,
                   settle_samples=design.settle_samples, nonlinear=nonlinear)
    stats.update(machine_time_s=design.machine_time_s + stats["level_check_s"], simulated_s=result["simulated_s"],
                 cycles=result["cycles"], peak_response_m=result["peak_response_m"],
                 peak_excitation_a=result["peak_excitation_a"])
    spectra = result["spectra"].reshape((design.realizations, design.experiments) + result["spectra"].shape[1:])
    return spectra, stats


def _check_scale(design, peak_response_m, response_target_m):
    """Level factor per axis from a level check (see `run_multisine`)."""
    peaks = design.excitation_peaks()
    scale = np.ones(len(ALL_AXES))
    for group in ([ALL_AXES.index(a) for a in RADIAL_AXES], [ALL_AXES.index(AXIAL_AXIS)]):
        active = [a for a in group if peaks[a] > 0]
        if not active:
            continue
        scale[active] = design.amplitude_max_a[active] / peaks[active]
        worst = max(peak_response_m[a] * scale[a] / response_target_m for a in active)
        scale[active] /= max(worst, 1.0)
    return scale


def _play(rig_model, design, members, rng, periods, record, settle_samples, nonlinear=True):
    """Simulate the given (realization, experiment) members for ``settle + periods`` periods."""
    n, t = design.samples_per_period, design.sample_time_s
    batch = len(members)
    waves = np.stack([design.waveforms(r, e) for r, e in members], axis=2)  # (5, N, B)
    waves = np.ascontiguousarray(np.moveaxis(waves, 1, 0))  # (N, 5, B)
    state = rig_model.initial_state(batch)
    total = settle_samples + periods * n
    buffer = np.empty((n, 20, batch), dtype=np.float32)
    lines = design.grid.lines
    spectra = np.zeros((batch, periods, 20, lines.size), dtype=complex) if record else None
    peak_response = np.zeros(len(ALL_AXES))
    peak_excitation = np.max(np.abs(waves), axis=(0, 2))
    for cycle in range(total):
        channels = rig_model.step(state, waves[cycle % n], rng, nonlinear=nonlinear)
        if cycle < settle_samples:
            continue
        position = cycle - settle_samples
        buffer[position % n] = channels
        if (position + 1) % n == 0:
            period = position // n
            v2 = buffer[:, 5:10, :].astype(float)
            peak_response = np.maximum(peak_response, np.max(np.abs(v2 - v2.mean(axis=0)), axis=(0, 2)))
            if record:
                coefficients = period_spectra(buffer.astype(float), lines, settle_samples + period * n)  # (L, 20, B)
                spectra[:, period] = np.transpose(coefficients, (2, 1, 0))
    out = {"peak_response_m": peak_response, "peak_excitation_a": peak_excitation, "cycles": total,
           "simulated_s": total * t}
    if record:
        out["spectra"] = spectra
    return out


# ------------------------------------------------------------------------------ a whole run
def pass_record(design, spectra):
    """A pass as `ambid.logs.multisine_frame` takes it."""
    return {"name": design.name, "lines": design.grid.lines, "frequency_hz": design.frequency_hz,
            "role": design.grid.role, "spectra": spectra, "reference": design.reference,
            "excites": design.grid.excites}


def measured_compliance(group):
    """``frequency_hz -> (n, 5, 5)`` magnitude of a coarse pass' measured radial dynamic compliance.

    Log-magnitude interpolated between the coarse lines (held beyond them);
    the zoom pass is shaped and levelled with it instead of the nominal model.
    """
    index = [ALL_AXES.index(a) for a in group.axes]
    logs = np.log(np.maximum(np.nan_to_num(group.compliance, nan=0.0), 1e-300))

    def compliance(frequency_hz):
        out = np.zeros((len(frequency_hz), len(ALL_AXES), len(ALL_AXES)))
        for i, a in enumerate(index):
            for j, b in enumerate(index):
                out[:, a, b] = np.exp(np.interp(frequency_hz, group.frequency_hz, logs[:, i, j]))
        return out

    return compliance


def identify_multisine(rig_model, plant, settings, seed=0, noise=True, fit_options=None, fit_channels="same_plane",
                       log=None):
    """A multisine identification run: coarse pass, its fit, the zoom pass around what the fit found.

    Parameters
    ----------
    rig_model : ambid.rig.RigModel
        The machine (virtual rig).
    plant : ambid.plant.Plant
        The engineer's model as built: shapes the coarse pass and serves the coarse fit
        (the known hold and effects); never the rig's truth.
    settings : MultisineSettings
    seed : int
        Seed of the design (grid, phases) and of the noise.
    noise : bool
    fit_options : dict, optional
        `ambid.channel_fit.fit_channel` options of the coarse fit (``modes``, ``orders``, ``delay``, ``lowpass``).
    fit_channels : str
        Channels whose features are zoomed (`ambid.channel_fit.select_channels`).
    log : logging.Logger, optional

    Returns
    -------
    passes : list of dict
        `pass_record` of each pass, with its ``stats`` (`run_multisine`) and ``design``.
    plan : dict
        ``features`` (the coarse fit's), ``bands_hz``, ``half_power_hz``, ``f0_hz``,
        ``settle_s`` of the zoom, ``skipped`` (channels the fit could not do) and ``notes``.
    """
    from .bla import pass_bla, bla_frf_table
    from .zoom import band_lines, fitted_features, zoom_bands

    say = log.info if log is not None else (lambda *args: None)
    coarse = design_multisine(plant, settings, seed)
    say("coarse pass: %d lines (%d excited) at %.4g Hz spacing, %d realization(s) x %d experiment(s) x %d periods",
        coarse.grid.lines.size, int((coarse.grid.role == "excited").sum()), coarse.f0_hz, coarse.realizations,
        coarse.experiments, coarse.periods)
    spectra, stats = run_multisine(rig_model, coarse, seed, noise, settings.level_check, settings.response_max_m, stream=0)
    say("coarse pass: %s; machine time %.1f s", "; ".join(stats["notes"]), stats["machine_time_s"])
    passes = [{**pass_record(coarse, spectra), "stats": stats, "design": coarse}]
    plan = {"features": [], "bands_hz": [], "half_power_hz": np.nan, "f0_hz": np.nan, "settle_s": np.nan,
            "skipped": [], "notes": []}
    if not settings.zoom:
        return passes, plan
    estimates = pass_bla(spectra, coarse.reference, coarse.grid.excites, coarse.frequency_hz, settings.design)
    if estimates["radial"] is None:
        plan["notes"].append("no radial axis excited: no zoom")
        return passes, plan
    table = bla_frf_table(estimates["radial"], estimates["axial"], estimates["siso"])
    features, skipped = fitted_features(table, plant, fit_channels, **(fit_options or {}))
    bands, half_power = zoom_bands(features, settings.zoom_width, settings.zoom_min_width, settings.radial_band_hz,
                                   settings.zoom_damping_max)
    plan.update(features=features, skipped=skipped)
    if not bands:
        plan["notes"].append("the coarse fit found no resonance or anti-resonance: no zoom")
        return passes, plan
    f0 = float(np.clip(half_power / settings.zoom_lines_per_bandwidth, settings.zoom_resolution_min_hz,
                       settings.frequency_resolution_hz))
    f0 = 1.0 / (round(1.0 / (f0 * coarse.sample_time_s)) * coarse.sample_time_s)
    lines = band_lines(bands, f0, settings.zoom_lines_per_band)
    slowest = max(1.0 / (2 * np.pi * row["damping_ratio"] * row["frequency_hz"]) for row in features
                  if row["damping_ratio"] <= settings.zoom_damping_max)
    settle = max(settings.settle_s, settings.zoom_settle_decays * slowest)
    plan.update(bands_hz=bands, half_power_hz=half_power, f0_hz=f0, settle_s=settle)
    zoom = zoom_design(plant, settings, seed, lines * f0, f0, compliance=measured_compliance(estimates["radial"]),
                       settle_s=settle)
    say("zoom pass: %d bands, %d lines at %.4g Hz spacing (narrowest half-power bandwidth %.3g Hz), settle %.2f s",
        len(bands), zoom.grid.lines.size, f0, half_power, settle)
    spectra, stats = run_multisine(rig_model, zoom, seed, noise, settings.level_check, settings.response_max_m, stream=1)
    say("zoom pass: %s; machine time %.1f s", "; ".join(stats["notes"]), stats["machine_time_s"])
    passes.append({**pass_record(zoom, spectra), "stats": stats, "design": zoom})
    return passes, plan
