"""Active flutter suppression on the linear ROM model: the reference control law, its discrete form, and the
closed-loop flutter speed with the control actuator and the loop delay (cascaded Padé sections).

Plant (``AeroelasticModel.continuous_matrices``): ``Mc y' = Ac y + b F``, y = (q, q_dot, xi); the trailing-edge
force F (N per metre span) enters the q_dot rows through ``L phi(1)``; the measured tip is ``w = L phi(1) . q``.
Loop: w -> (sensor, no dynamics) -> controller C(s) -> loop delay e^{-s tau} (Padé sections) -> actuator
``wa / (s + wa)`` (rate limit and saturation are not in the linear model) -> F.

Reference law (designed here, run by ``panel_rig.ros.controller``): filtered tip-rate feedback,

    C(s) = -g * s / (1 + s/wd)

g in N s/m^2 (N/m of force per m/s of tip velocity). Pure functions on arrays; no ROS, no wall clock.
"""

from __future__ import annotations

import itertools
import math
import warnings
from dataclasses import asdict, dataclass, field

import numpy as np
import scipy.linalg
import scipy.signal

from panel_rig.analysis.flutter import edges_to_ranges, find_flutter, instability_edges
from panel_rig.config import PanelConfig
from panel_rig.model.aerodynamics import MAX_AIRSPEED_MPS
from panel_rig.model.aeroelastic import AeroelasticModel
from panel_rig.model.structure import mode_shapes

#: sensor noise assumed by the design (1-sigma white noise on the measured tip w per reading), m: the sensor's default
SENSOR_NOISE_M = PanelConfig().sensor_tip_noise_m
#: "quiet": tip RMS below this many times the sensor noise (200 um). In the default tunnel (0.1 % turbulence) the
#: panel's random response below flutter is 25-50 um (5-10x the noise, docs/validation.md section 7) and the
#: open-loop LCO just past flutter ~27 mm (5000x): 40x separates "no flutter" from flutter with margin both ways.
QUIET_FACTOR = 40.0
PADE_ORDER = 4
#: the loop delay's model is accurate up to this frequency: above the loop's filters (actuator 100 Hz, derivative
#: corner 150 Hz) and the panel's third mode (73 Hz), the highest the model has
DELAY_ACCURATE_HZ = 200.0
#: phase of one Padé section at DELAY_ACCURATE_HZ: a 4th-order section is then 0.001 degrees off (0.36 at 4 rad)
PADE_SECTION_RAD = 2.0


@dataclass(frozen=True)
class StateSpace:
    """x' = A x + B u, y = C x + D u (SISO)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray

    @property
    def n(self) -> int:
        return self.A.shape[0]

    def freqresp(self, f_hz: np.ndarray) -> np.ndarray:
        s = 2j * np.pi * np.atleast_1d(np.asarray(f_hz, dtype=float))
        eye = np.eye(self.n)
        out = np.empty(s.size, dtype=complex)
        for i, si in enumerate(s):
            out[i] = (self.C @ np.linalg.solve(si * eye - self.A, self.B) + self.D).item() if self.n else self.D.item()
        return out


def tf_ss(num: np.ndarray, den: np.ndarray) -> StateSpace:
    """Transfer function (descending powers of s) to state space."""
    with warnings.catch_warnings():  # a Padé numerator's leading terms are tiny in seconds: harmless here
        warnings.simplefilter("ignore", scipy.signal.BadCoefficients)
        A, B, C, D = scipy.signal.tf2ss(np.atleast_1d(num), np.atleast_1d(den))
    return StateSpace(np.atleast_2d(A), np.atleast_2d(B).reshape(-1, 1), np.atleast_2d(C).reshape(1, -1),
                      np.atleast_2d(D).reshape(1, 1))


def series(a: StateSpace, b: StateSpace) -> StateSpace:
    """b after a (u -> a -> b -> y)."""
    A = np.block([[a.A, np.zeros((a.n, b.n))], [b.B @ a.C, b.A]])
    B = np.vstack([a.B, b.B @ a.D])
    C = np.hstack([b.D @ a.C, b.C])
    return StateSpace(A, B, C, b.D @ a.D)


def pade_delay(tau_s: float, order: int = PADE_ORDER, accurate_to_hz: float = DELAY_ACCURATE_HZ) -> StateSpace:
    """e^{-s tau} as a cascade of Padé approximants of the given order, each for an equal part of tau, so many that
    each part's phase at ``accurate_to_hz`` is at most PADE_SECTION_RAD (identity for tau = 0).

    One 4th-order approximant of the whole delay was wrong past omega tau ~ 4: at 50 ms it gave the reference law
    a closed-loop U_f of 13.97 m/s where the loop is unstable from low speed (the emulated rig aborted)."""
    if tau_s <= 0:
        return StateSpace(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.ones((1, 1)))
    sections = max(1, math.ceil(2 * math.pi * accurate_to_hz * tau_s / PADE_SECTION_RAD))
    part = tau_s / sections
    n = order
    c = np.array([math.factorial(2 * n - k) * math.factorial(n) / (math.factorial(2 * n) * math.factorial(k)
                                                                   * math.factorial(n - k)) for k in range(n + 1)])
    den = (c * part ** np.arange(n + 1))[::-1]
    num = (c * (-part) ** np.arange(n + 1))[::-1]
    one = tf_ss(num, den)
    out = one
    for _ in range(sections - 1):
        out = series(out, one)
    return out


def first_order(bandwidth_hz: float) -> StateSpace:
    """wa / (s + wa): the control actuator's linear model."""
    wa = 2 * math.pi * bandwidth_hz
    return tf_ss([wa], [1.0, wa])


@dataclass(frozen=True)
class ControlLaw:
    """The reference law C(s) = -g s / (1 + s/wd): gain g (N/m of force per m/s of tip velocity), derivative
    filter corner (Hz)."""

    gain_nspm2: float = 0.0
    derivative_hz: float = 150.0

    def state_space(self) -> StateSpace:
        wd = 2 * math.pi * self.derivative_hz
        return tf_ss([-self.gain_nspm2 * wd, 0.0], [1.0, wd])

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


class DiscreteLaw:
    """The law in discrete time (Tustin) for a controller running at its reading rate; the sample period is taken
    from the readings' stamps (a lost reading lengthens it), and each distinct period is discretised once."""

    def __init__(self, law: ControlLaw) -> None:
        self.law = law
        self.ss = law.state_space()
        self._cache: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
        self.reset()

    def reset(self) -> None:
        self.x = np.zeros(self.ss.n)
        self._w_prev: float | None = None

    def _matrices(self, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        key = round(dt_s * 1e6)
        if key not in self._cache:
            s = self.ss
            Ad, Bd, Cd, Dd, _ = scipy.signal.cont2discrete((s.A, s.B, s.C, s.D), key * 1e-6, method="bilinear")
            self._cache[key] = (Ad, Bd.reshape(-1), Cd.reshape(-1), Dd.reshape(()))
            if len(self._cache) > 64:
                self._cache.pop(next(iter(self._cache)))
        return self._cache[key]

    def step(self, w_m: float, dt_s: float) -> float:
        """Force command (N/m) for the tip reading w (m) taken dt_s after the previous one."""
        if self._w_prev is None:  # first sample: the filter starts in steady state at this reading (no kick)
            self.x = -np.linalg.solve(self.ss.A, self.ss.B[:, 0] * w_m) if self.ss.n else self.x
        self._w_prev = w_m
        Ad, Bd, Cd, Dd = self._matrices(max(dt_s, 1e-6))
        y = float(Cd @ self.x + Dd * w_m)  # C(0) = 0: a static tip offset gives no force
        self.x = Ad @ self.x + Bd * w_m
        return y


@dataclass(frozen=True)
class LoopModel:
    """Everything between the law's output and the force on the panel: actuator bandwidth and loop delay."""

    actuator_bandwidth_hz: float = 100.0
    delay_s: float = 0.0
    pade_order: int = PADE_ORDER
    delay_accurate_hz: float = DELAY_ACCURATE_HZ


def plant_io(model: AeroelasticModel, rom_modes: int | None) -> tuple[np.ndarray, np.ndarray]:
    """(b, c): force input column (q_dot rows: L phi(1) per N/m) and tip output row (w = L phi(1) . q)."""
    s = model.structure
    n = s.n_modes
    r = model.continuous(rom_modes).n_aero
    tip = model.cfg.panel_length_m * mode_shapes(n, np.array([1.0]))[:, 0]
    b = np.zeros(2 * n + r)
    b[n: 2 * n] = tip
    c = np.zeros(2 * n + r)
    c[:n] = tip
    return b, c


def closed_loop_eigenvalues(model: AeroelasticModel, airspeed_mps: float, law: ControlLaw, loop: LoopModel,
                            rom_modes: int | None = None) -> np.ndarray:
    """Eigenvalues (1/s) of plant + law + delay + actuator at U (descriptor form, generalized eigenproblem)."""
    rom_modes = model.cfg.rom_modes if rom_modes is None else rom_modes
    Mc, Ac = model.continuous_matrices(airspeed_mps, rom_modes)
    b, c = plant_io(model, rom_modes)
    chain = series(series(law.state_space(), pade_delay(loop.delay_s, loop.pade_order, loop.delay_accurate_hz)),
                   first_order(loop.actuator_bandwidth_hz))  # w -> F
    # explicit form (Mc is invertible): the generalized QZ problem mixes the plant's ill-conditioned Mc with the
    # filters' large coefficients and returns spurious unstable roots
    A0 = np.linalg.solve(Mc, Ac)
    b0 = np.linalg.solve(Mc, b)
    A = np.block([[A0 + np.outer(b0, chain.D.item() * c), np.outer(b0, chain.C)],
                  [chain.B @ c[None, :], chain.A]])
    s = scipy.linalg.eigvals(A)
    return s[np.isfinite(s)]


def growth_rate(model: AeroelasticModel, airspeed_mps: float, law: ControlLaw, loop: LoopModel,
                rom_modes: int | None = None) -> float:
    return float(np.max(closed_loop_eigenvalues(model, airspeed_mps, law, loop, rom_modes).real))


@dataclass(frozen=True)
class ClosedLoopFlutter:
    speed_mps: float | None  # None: stable up to u_max (or unstable already at u_min)
    frequency_hz: float | None
    unstable_at_low_speed: bool = False
    #: with ``all_ranges``: every airspeed interval (m/s) of the scan with a closed-loop Re s > 0, (start, end); end
    #: None when it lasts to u_max, start u_min when it is unstable already there. A long loop delay can make the
    #: loop unstable over a band of low speeds and stable again above it, below its flutter speed (50 ms: 0.55 to
    #: ~3 m/s)
    unstable_ranges_mps: tuple[tuple[float, float | None], ...] = ()


def closed_loop_flutter(model: AeroelasticModel, law: ControlLaw, loop: LoopModel, rom_modes: int | None = None,
                        u_min: float = 0.5, u_max: float = 30.0, n_scan: int = 60,
                        all_ranges: bool = False) -> ClosedLoopFlutter:
    """Lowest airspeed where a closed-loop eigenvalue crosses into Re s > 0 (scan, then Brent; a window narrower
    than the scan step is found too: :func:`panel_rig.analysis.flutter.instability_edges`). ``all_ranges``: the
    scan goes on to u_max and every unstable interval is refined (``unstable_ranges_mps``)."""
    speeds = np.linspace(u_min, u_max, n_scan)
    edges_found = instability_edges(lambda u: closed_loop_eigenvalues(model, u, law, loop, rom_modes), speeds,
                                    xtol_mps=1e-5)
    edges = list(edges_found if all_ranges else itertools.islice(edges_found, 1))
    low = bool(edges) and growth_rate(model, u_min, law, loop, rom_modes) > 0
    ranges = tuple(edges_to_ranges(edges)) if all_ranges else ()
    if low:
        return ClosedLoopFlutter(None, None, unstable_at_low_speed=True, unstable_ranges_mps=ranges)
    if not edges:
        return ClosedLoopFlutter(None, None)
    uf = edges[0]
    s = closed_loop_eigenvalues(model, uf + 1e-4, law, loop, rom_modes)
    i = int(np.argmax(s.real))
    return ClosedLoopFlutter(float(uf), float(abs(s[i].imag) / (2 * np.pi)), unstable_ranges_mps=ranges)


@dataclass(frozen=True)
class Design:
    """A designed law and what the design assumed and predicts."""

    law: ControlLaw
    loop: LoopModel
    open_loop_flutter_mps: float
    closed_loop_flutter_mps: float | None
    design_airspeed_mps: float
    sensor_noise_m: float = SENSOR_NOISE_M
    notes: dict[str, float] = field(default_factory=dict)


#: loop delay assumed by the design when none is measured: ~2 ms loopback command age + half a 500 Hz sample
DESIGN_DELAY_S = 0.003
#: the law must not make things worse (closed-loop U_f >= open-loop U_f, no low-speed instability) with the loop
#: delay this many times the design delay
ROBUST_DELAY_FACTOR = 2.5
DESIGN_GAINS = tuple(np.round(np.arange(0.05, 1.001, 0.05), 3))


def effective_delay(command_age_s: float, command_rate_hz: float, dt_s: float) -> float:
    """Loop delay of the linear model for a measured mean command age: the age (reading stamp -> command acting),
    plus half a command period (the held command: zero-order hold) and half a physics step (the command acts
    from the first step that starts after its arrival)."""
    return command_age_s + 0.5 / command_rate_hz + 0.5 * dt_s


def design_law(model: AeroelasticModel, actuator_bandwidth_hz: float = 100.0, delay_s: float = DESIGN_DELAY_S,
               derivative_hz: float = 150.0, rom_modes: int | None = None,
               gains: tuple[float, ...] = DESIGN_GAINS) -> Design:
    """The reference law for this model: the largest rate-feedback gain (from ``gains``) that stays robust for any
    loop delay from 0 to ROBUST_DELAY_FACTOR x the design delay (no instability at low speed, closed-loop U_f not below the open-loop
    one). Larger gain raises U_f further (the delay-free optimum is far higher) but the delay destabilises the
    third mode (~70 Hz) and, at low speed, the second: robustness to the delay bounds the gain."""
    rom_modes = model.cfg.rom_modes if rom_modes is None else rom_modes
    open_fp = find_flutter(model, aero="rom", rom_modes=rom_modes, formulation="continuous")
    if open_fp is None:
        raise ValueError(f"the open-loop model does not flutter below {MAX_AIRSPEED_MPS:g} m/s: nothing to suppress")
    u_max = 2.5 * open_fp.speed_mps
    delays = np.linspace(0.0, ROBUST_DELAY_FACTOR * delay_s, 6)
    chosen = None

    def robust(law: ControlLaw) -> bool:
        for d in delays:
            r = closed_loop_flutter(model, law, LoopModel(actuator_bandwidth_hz, float(d)), rom_modes, u_max=u_max,
                                    n_scan=25)
            if r.unstable_at_low_speed or (r.speed_mps is not None and r.speed_mps < open_fp.speed_mps):
                return False
        return True

    for g in sorted(gains):
        law = ControlLaw(float(g), derivative_hz)
        if not robust(law):
            break
        chosen = law
    if chosen is None:
        raise ValueError("no gain is robust to the loop delay: shorten the loop or lower the delay")
    loop = LoopModel(actuator_bandwidth_hz, delay_s)
    cl = closed_loop_flutter(model, chosen, loop, rom_modes, u_max=u_max, n_scan=40)
    return Design(chosen, loop, open_fp.speed_mps, cl.speed_mps, open_fp.speed_mps,
                  notes={"open_loop_flutter_frequency_hz": open_fp.frequency_hz,
                         "closed_loop_flutter_frequency_hz": cl.frequency_hz or math.nan,
                         "robust_delay_s": float(delays[-1])})


def noise_force_rms(law: ControlLaw, rate_hz: float, noise_m: float = SENSOR_NOISE_M) -> float:
    """RMS force command (N/m) that white sensor noise of ``noise_m`` per reading produces through the discrete
    law at ``rate_hz`` (impulse-response energy)."""
    d = DiscreteLaw(law)
    d.step(0.0, 1.0 / rate_hz)
    d.reset()
    d._w_prev = 0.0
    h = [d.step(1.0, 1.0 / rate_hz)] + [d.step(0.0, 1.0 / rate_hz) for _ in range(2000)]
    return float(noise_m * np.sqrt(np.sum(np.square(h))))


def damping_curves(model: AeroelasticModel, speeds: np.ndarray, law: ControlLaw | None, loop: LoopModel,
                   rom_modes: int | None = None, f_max_hz: float = 100.0) -> list[np.ndarray]:
    """Eigenvalues per airspeed, open loop (law None) or closed loop, keeping the structural range (|f| < f_max)
    without the filters' own fast poles."""
    out = []
    rom_modes = model.cfg.rom_modes if rom_modes is None else rom_modes
    for u in speeds:
        if law is None:
            Mc, Ac = model.continuous_matrices(float(u), rom_modes)
            s = scipy.linalg.eigvals(np.linalg.solve(Mc, Ac))
        else:
            s = closed_loop_eigenvalues(model, float(u), law, loop, rom_modes)
        out.append(s[(np.abs(s.imag) / (2 * np.pi) < f_max_hz) & (s.real > -60)])
    return out
