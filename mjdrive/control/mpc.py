"""Longitudinal manoeuvres by model predictive control: one quadratic programme solved by OSQP each control step.

State x_k = (s_k, v_k, a_k): position [m] along the path (0 = the front bumper now), speed [m/s], acceleration
[m/s^2]; input j_k: jerk [m/s^3], held over each of the N steps of `step` seconds (exact integration):

    s+ = s + v h + a h^2 / 2 + j h^3 / 6,   v+ = v + a h + j h^2 / 2,   a+ = a + j h

Cost: sum over the horizon of w_v (v_k - v_ref_k)^2 + w_a a_k^2 + w_j j_k^2, plus the slacks' penalties.
Hard bounds: the comfort envelope, a_k in [accel_min, accel_max] and j_k in [jerk_min, jerk_max], and v_k >= 0 (the
car does not reverse; the initial acceleration is limited so that it can always stop without reversing,
`initial_accel`). Soft constraints, each relaxed by a slack that costs far more than anything else (so the problem
is always feasible):

    follow:  s_k + T v_k <= leader_k - d0      (the time gap T and standstill gap d0 to the leader's rear, with
                                                the leader's predicted motion: constant acceleration, never
                                                reversing)
    stop:    s_k <= stop                       (come to rest before a point: a give-way line, a lane's end)
    v_k <= v_ref_k                             (the reference is the most the route allows)

The three modes of study 002's operative level (§4.3) are which of these bind: cruise (track v_ref), follow
(the leader) and stop (the point). A stop also lowers v_ref to the comfortable stopping profile
sqrt(2 b (stop - s)), so the car brakes early and gently instead of late and hard.

OSQP: the matrices are built once (fixed sparsity); a solve updates only the vectors (q, l, u) and starts from the
previous solution (OSQP's warm start); a solution is moved onto the hard bounds it exceeds (within OSQP's tolerance,
or more when it stopped early) and its states integrated exactly (`plan_within_bounds`). A comfort solve runs at
most ITERATION_BUDGET iterations (a real-time budget, as real-time MPC schemes bound their iterations): most
converge in 10-30; the few that reach the budget (about 3% of the control periods of a drive in traffic, at changes
of leader or mode) give a plan whose first acceleration is within about 0.2 m/s^2 of the converged one (0.02 at the
99th percentile), and the next period's solve goes on from it. For the same inputs a solver gives the same bits:
the settings leave nothing to time (rho adapts every `adaptive_rho_interval` iterations, no time limit), and `reset`
sets the solver up anew so every episode starts from the same state. Fallbacks: when the comfort envelope cannot
keep the car behind a leader's rear by `emergency_gap` or before a stop point (e.g. a vehicle cutting in), the same
programme is solved again, to convergence, with the firm bounds (harder braking, a jerk bound still near nuPlan's
comfort limit), and if those cannot either, with the emergency bounds: a graded response, so that a cut-in that
needs a little more than comfort gets a little more, not the full brake; if OSQP does not report a solution, the
plan is a comfortable braking to rest (`MPCPlan.fallback`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import osqp
import scipy.sparse as sparse

from mjdrive.compiled import inline, jit
from mjdrive.config import Config, ConfigError, param

INFINITY = osqp.ext_builtin.OSQP_INFTY  # OSQP's infinite bound (1e30)
MODES = ("cruise", "follow", "stop")  # the plan's mode: the soft constraint that binds first (within BINDING)
BINDING = 0.1  # [m]
INTRUSION_TOLERANCE = 0.05  # [m] a plan passing a stop point, or the emergency gap, by less needs no firmer bounds
NO_LIMIT = 1e30  # [m] a position bound that never binds: OSQP_INFTY (OSQP leaves it out of its infeasibility checks)


@dataclass(frozen=True)
class MPCConfig(Config):
    """The longitudinal MPC's horizon, bounds, gaps and weights."""

    horizon: int = param(20, "prediction steps", ge=5, le=60)
    step: float = param(0.25, "length of one prediction step", "s", gt=0.02, le=1.0)
    accel_min: float = param(-3.5, "comfort bound: strongest braking", "m/s^2", ge=-9.0, lt=0.0)
    accel_max: float = param(1.8, "comfort bound: strongest acceleration", "m/s^2", gt=0.0, le=5.0)
    jerk_max: float = param(2.5, "comfort bound on |jerk|", "m/s^3", gt=0.0, le=50.0)
    firm_accel_min: float = param(-5.0, "braking allowed when the comfort bounds cannot keep a gap (tried first)",
                                  "m/s^2", ge=-10.0, lt=0.0)
    firm_jerk_max: float = param(5.0, "|jerk| allowed then", "m/s^3", gt=0.0, le=200.0)
    emergency_accel_min: float = param(-8.0, "braking allowed when the firm bounds cannot keep a gap either", "m/s^2",
                                       ge=-10.0, lt=0.0)
    emergency_jerk_max: float = param(25.0, "|jerk| allowed in an emergency", "m/s^3", gt=0.0, le=200.0)
    emergency_gap: float = param(1.5, "a comfort plan that comes closer than this to a leader's rear (or passes a "
                                 "stop point) is solved again with the firm bounds, and a firm one with the "
                                 "emergency bounds", "m", ge=0.0, le=10.0)
    headway: float = param(1.5, "T: time gap to the leader", "s", ge=0.0, le=5.0)
    standstill_gap: float = param(4.0, "d0: gap to the leader at rest (bumper to bumper)", "m", ge=0.5, le=20.0)
    stop_decel: float = param(1.5, "b: the comfortable stopping profile's deceleration", "m/s^2", gt=0.1, le=5.0)
    speed_weight: float = param(1.0, "w_v", "1/(m/s)^2", gt=0.0)
    accel_weight: float = param(0.5, "w_a", "1/(m/s^2)^2", ge=0.0)
    jerk_weight: float = param(1.0, "w_j", "1/(m/s^3)^2", gt=0.0)
    slack_weight: float = param(1e2, "quadratic cost of a slack", "1/m^2", gt=0.0)
    slack_linear: float = param(1e2, "linear cost of a slack (an exact penalty)", "1/m", gt=0.0)

    def check(self) -> None:
        if not self.emergency_accel_min <= self.firm_accel_min <= self.accel_min or not (
                self.jerk_max <= self.firm_jerk_max <= self.emergency_jerk_max):
            raise ConfigError("each bound must contain the one before: emergency_accel_min <= firm_accel_min <= "
                              "accel_min and jerk_max <= firm_jerk_max <= emergency_jerk_max")

    def tier(self, level: int) -> tuple[float, float]:
        """(strongest braking [m/s^2], |jerk| bound [m/s^3]) of TIERS[level]: comfort, firm, emergency."""
        return ((self.accel_min, self.jerk_max), (self.firm_accel_min, self.firm_jerk_max),
                (self.emergency_accel_min, self.emergency_jerk_max))[level]


TIERS = ("solved", "firm", "emergency")  # a plan's status by the bounds it was solved within (else "fallback")


ITERATION_BUDGET = 100  # OSQP iterations of a comfort solve: a real-time budget (see the module doc)
SOLVER_SETTINGS = dict(  # fixed: OSQP's result depends only on the problem sequence since `setup`
    eps_abs=1e-3, eps_rel=1e-3, rho=1.0, check_termination=5, adaptive_rho=True, adaptive_rho_interval=25,
    max_iter=4000, polishing=False, warm_starting=True, verbose=False, time_limit=1e10)  # 1e10 s: none
_USABLE = (osqp.ext_builtin.OSQP_SOLVED, osqp.ext_builtin.OSQP_SOLVED_INACCURATE,
           osqp.ext_builtin.OSQP_MAX_ITER_REACHED)  # statuses whose solution a plan starts from


class OSQPSolver:
    """OSQP's C solver through its Python extension (`osqp.ext_builtin`: the object the `osqp.OSQP` wrapper holds),
    set up once and then given only new vectors: a solve without the wrapper's per-call bookkeeping (about 30 us
    of a 70 us solve here)."""

    def __init__(self, p, q: np.ndarray, a, l: np.ndarray, u: np.ndarray, settings: dict):
        ext = osqp.ext_builtin
        options = ext.OSQPSettings()
        ext.osqp_set_default_settings(options)
        for name, value in settings.items():
            setattr(options, name, value)
        self._solver = ext.OSQPSolver(ext.CSC(p.astype(np.float64)), q, ext.CSC(a.astype(np.float64)), l, u,
                                      a.shape[0], a.shape[1], options)
        self._budgets: dict[int, object] = {}  # settings by iteration budget
        self._budget = options.max_iter

    def solve(self, q: np.ndarray, l: np.ndarray, u: np.ndarray, budget: int | None = None
              ) -> tuple[np.ndarray | None, int, bool]:
        """For the new vectors: the solution (None when OSQP gives none it could use: infeasible, non-finite), its
        iterations, and whether it converged (else it stopped at the iteration budget, at most `budget` iterations
        (None: the settings' max_iter), or reports it inaccurate)."""
        solver = self._solver
        if budget is not None and budget != self._budget:
            self._set_budget(budget)
        solver.update_data_vec(q, l, u)  # (q, l, u): positional, a little cheaper than by keyword
        solver.solve()
        info = solver.info
        x = solver.solution.x if info.status_val in _USABLE else None
        if x is not None and not math.isfinite(x.sum()):  # a sum of finite values is finite (|x| << 1e300 here)
            x = None
        return x, int(info.iter), info.status_val == osqp.ext_builtin.OSQP_SOLVED

    def _set_budget(self, budget: int) -> None:
        if budget not in self._budgets:
            options = self._solver.get_settings()
            options.max_iter = budget
            self._budgets[budget] = options
        self._solver.update_settings(self._budgets[budget])
        self._budget = budget


@dataclass(frozen=True)
class Leader:
    """The vehicle to follow: its rear bumper `gap` [m] ahead of the ego's front bumper, its speed along the
    ego's path [m/s] and acceleration [m/s^2] (predicted constant, until it stands). `alongside`: its rear is not
    ahead of the ego's front (a road user moving in beside it, a zipper's partner at a merge): while it is at least
    as fast as the car, the car falls in behind it braking at most within the firm bounds (it pulls away; the
    emergency bounds are for what the car closes on)."""

    gap: float
    speed: float
    accel: float = 0.0
    alongside: bool = False

    def positions(self, times: np.ndarray) -> np.ndarray:
        """Its rear bumper [m] (ego front now = 0) at `times` [s] (`rear_at`)."""
        return rear_positions(self.gap, self.speed, self.accel, np.asarray(times, dtype=float))


@dataclass(frozen=True)
class MPCPlan:
    """A solution: positions, speeds, accelerations (N + 1,) and jerks (N,) at the horizon's steps."""

    s: np.ndarray  # [m]
    v: np.ndarray  # [m/s]
    a: np.ndarray  # [m/s^2]
    j: np.ndarray  # [m/s^3]
    slack: float  # [m] the largest violation of a soft constraint
    mode: str  # "cruise", "follow" or "stop": the constraint that binds first (cruise: none)
    status: str  # "solved", "firm" or "emergency" (solved with those bounds, TIERS) or "fallback" (OSQP failed)
    iterations: int
    intrusion: float = 0.0  # [m] how far it passes a stop point or comes within emergency_gap of a leader, less
    #                         INTRUSION_TOLERANCE (> 0: solved again with the firm bounds)
    converged: bool = True  # False: OSQP stopped at ITERATION_BUDGET (the plan still meets the hard bounds)
    intrusion_ahead: float = 0.0  # [m] the same, leaders alongside left out (> 0 after the firm bounds: emergency)

    def accel_at(self, t: float, step: float) -> float:
        """The planned acceleration [m/s^2] t [s] from now (piecewise linear: constant jerk per step)."""
        k = min(int(t / step), len(self.j) - 1)
        return float(self.a[k] + self.j[k] * (t - k * step))

    def speed_at(self, t: float, step: float) -> float:
        k = min(int(t / step), len(self.j) - 1)
        tau = t - k * step
        return float(self.v[k] + self.a[k] * tau + 0.5 * self.j[k] * tau * tau)


class LongitudinalMPC:
    """The QP of the module docstring, set up once; `solve` updates its vectors."""

    def __init__(self, config: MPCConfig = MPCConfig()):
        self.config = c = config
        n, h = c.horizon, c.step
        self.times = h * np.arange(n + 1)  # [s]
        self._times_ahead = self.times[1:]  # [s] steps 1..N
        self._nx = 3 * n  # the states of steps 1..N (step 0's is given: it enters the first dynamics rows' bounds)
        nv = self._nx + 3 * n  # states, jerks, position slacks, speed slacks
        self._x = lambda k, i: 3 * (k - 1) + i
        self._j = lambda k: self._nx + k
        self._slack = lambda k: self._nx + n + k  # the position slack of step k + 1
        self._speed_slack = lambda k: self._nx + 2 * n + k
        rows, cols, vals = [], [], []
        row = 0

        def put(col: int, value: float) -> None:
            rows.append(row)
            cols.append(col)
            vals.append(value)

        transition = np.array([[1.0, h, h * h / 2], [0.0, 1.0, h], [0.0, 0.0, 1.0]])
        gain = np.array([h**3 / 6, h * h / 2, h])
        for k in range(n):  # dynamics: A x_k + B j_k - x_{k+1} = 0 (for k = 0: B j_0 - x_1 = -A x_0)
            for i in range(3):
                for m in range(3):
                    if transition[i, m] and k > 0:
                        put(self._x(k, m), transition[i, m])
                put(self._j(k), gain[i])
                put(self._x(k + 1, i), -1.0)
                row += 1
        self._n_eq = row
        self._rows_accel = row
        for k in range(1, n + 1):
            put(self._x(k, 2), 1.0)
            row += 1
        self._rows_jerk = row
        for k in range(n):
            put(self._j(k), 1.0)
            row += 1
        self._rows_limit = row
        # 0 <= v_k - mu_k <= v_max_k: the speed limit, soft, and v_k >= 0, hard (`initial_accel` keeps it feasible):
        # v_k >= mu_k >= 0, and a slack mu_k > 0 only where v_k passes v_max_k >= 0, so v_k >= mu_k costs nothing
        for k in range(1, n + 1):
            put(self._x(k, 1), 1.0)
            put(self._speed_slack(k - 1), -1.0)
            row += 1
        self._rows_stop = row
        for k in range(1, n + 1):  # s_k - sigma_k <= stop
            put(self._x(k, 0), 1.0)
            put(self._slack(k - 1), -1.0)
            row += 1
        self._rows_follow = row
        for k in range(1, n + 1):  # s_k + T v_k - sigma_k <= leader_k - d0
            put(self._x(k, 0), 1.0)
            put(self._x(k, 1), c.headway)
            put(self._slack(k - 1), -1.0)
            row += 1
        self._rows_slack = row
        for k in range(2 * n):  # slacks >= 0
            put(self._slack(0) + k, 1.0)
            row += 1
        self._a = sparse.csc_matrix((vals, (rows, cols)), shape=(row, nv))
        diag = np.zeros(nv)
        for k in range(1, n + 1):
            diag[self._x(k, 1)] = 2 * c.speed_weight
            diag[self._x(k, 2)] = 2 * c.accel_weight
        diag[self._j(0): self._j(0) + n] = 2 * c.jerk_weight
        diag[self._slack(0): self._slack(0) + 2 * n] = 2 * c.slack_weight
        self._p = sparse.diags(diag).tocsc()
        self._q = np.zeros(nv)
        self._q[self._slack(0): self._slack(0) + 2 * n] = c.slack_linear
        self._l = np.full(row, -INFINITY)
        self._u = np.full(row, INFINITY)
        self._l[: self._n_eq] = self._u[: self._n_eq] = 0.0
        self._start = np.zeros(3)  # (s, v, a) of step 0: 0 [m], the speed [m/s] and acceleration [m/s^2] now
        # views of the vectors a solve updates (the vectors are only ever changed in place)
        self._limit = self._u[self._rows_limit: self._rows_limit + n]  # [m/s] v_max_k
        self._stop = self._u[self._rows_stop: self._rows_stop + n]  # [m] the stop point (NO_LIMIT: none)
        self._follow = self._u[self._rows_follow: self._rows_follow + n]  # [m] the leaders' rears less d0
        self._speed_cost = self._q[self._x(1, 1): self._x(n, 1) + 1: 3]  # -2 w_v v_ref_k
        self._l[self._rows_limit: self._rows_limit + n] = 0.0  # v_k - mu_k >= 0
        self._l[self._rows_slack:] = 0.0
        self._set_bounds(0)
        self._initial = (self._q.copy(), self._l.copy(), self._u.copy())  # the vectors a solver is set up with
        self._ahead = np.full(n, NO_LIMIT)  # [m] the follow bounds of the leaders ahead (not alongside)
        self.solver: OSQPSolver | None = None
        self.reset()

    @property
    def size(self) -> tuple[int, int, int]:
        """(variables, constraints, non-zeros of the constraint matrix)."""
        return self._a.shape[1], self._a.shape[0], self._a.nnz

    def reset(self) -> None:
        """A fresh solver set up with the initial vectors (OSQP's scaling reads q at set-up; warm start and rho as
        after it): an episode's solves depend only on its inputs, not on the episodes before."""
        self._q[:], self._l[:], self._u[:] = self._initial
        self._tier = 0
        self.solver = OSQPSolver(self._p, self._q, self._a, self._l, self._u, SOLVER_SETTINGS)

    def _set_bounds(self, tier: int) -> None:
        c, n = self.config, self.config.horizon
        a_min, j_max = c.tier(tier)
        self._l[self._rows_accel: self._rows_accel + n] = a_min
        self._u[self._rows_accel: self._rows_accel + n] = c.accel_max
        self._l[self._rows_jerk: self._rows_jerk + n] = -j_max
        self._u[self._rows_jerk: self._rows_jerk + n] = j_max
        self._tier = tier

    def initial_accel(self, speed: float, accel: float) -> float:
        """The acceleration the plan starts from: `accel` within the comfort bounds, and no more braking than the
        jerk bound can take back before the car stands (-sqrt(2 j_max v)): a car that stops does not go on
        decelerating, and a plan from there must stop without reversing (v >= 0 is a hard bound)."""
        c = self.config
        v = max(speed, 0.0)
        return min(max(accel, c.accel_min, -v / c.step, -math.sqrt(2.0 * c.jerk_max * v)), c.accel_max)

    def solve(self, speed: float, accel: float, v_ref: np.ndarray | float, stop: float | None = None,
              leaders: Sequence[Leader] = (), stop_moves: bool = False) -> MPCPlan:
        """The plan from the current speed [m/s] and acceleration [m/s^2] (`initial_accel` of them) tracking the
        reference speeds v_ref [m/s] (a number, or one per step 1..N), never faster than them (a soft bound),
        the front bumper coming to rest at most `stop` [m] ahead (None: no stop) and keeping its gap to each of
        `leaders`. `stop_moves`: the stop point comes towards the car (a road user crossing): a plan passing it
        goes to the emergency bounds at once, as the firm plan's static point would be behind the truth."""
        c = self.config
        v0, a0 = max(speed, 0.0), self.initial_accel(speed, accel)
        limit = self._limit
        limit[:] = v_ref
        if stop is None:
            np.multiply(limit, -2.0 * c.speed_weight, out=self._speed_cost)
            self._stop[:] = NO_LIMIT
        else:  # the comfortable stopping profile v = sqrt(2 b (stop - s)), in time from here
            start = math.sqrt(2.0 * c.stop_decel * max(stop, 0.0))
            ref = np.minimum(limit, np.maximum(start - c.stop_decel * self._times_ahead, 0.0))
            np.multiply(ref, -2.0 * c.speed_weight, out=self._speed_cost)
            self._stop[:] = stop
        h, lower, upper = c.step, self._l, self._u
        self._start[1], self._start[2] = v0, a0
        lower[0] = upper[0] = -(v0 * h + a0 * h * h / 2)  # -A x_0 (element by element: no array made per solve)
        lower[1] = upper[1] = -(v0 + a0 * h)
        lower[2] = upper[2] = -a0
        follow = self._follow
        follow[:] = self._ahead[:] = NO_LIMIT
        for leader in leaders:
            fold_leader(leader.gap, leader.speed, leader.accel, self._times_ahead, c.standstill_gap, follow,
                        self._ahead, not (leader.alongside and leader.speed >= v0))
        if self._tier:
            self._set_bounds(0)
        plan = self._solve(0)
        if plan is not None and plan.intrusion > 0.0:  # firmer bounds while a plan moves into a leader or past a stop
            if not stop_moves:
                self._set_bounds(1)
                plan = self._solve(1) or plan
            if stop_moves or plan.intrusion_ahead > 0.0:
                self._set_bounds(2)
                plan = self._solve(2) or plan
        return plan if plan is not None else self.fallback(v0, a0)

    def _solve(self, tier: int) -> MPCPlan | None:
        budget = min(ITERATION_BUDGET, SOLVER_SETTINGS["max_iter"]) if tier == 0 else SOLVER_SETTINGS["max_iter"]
        solution, iterations, converged = self.solver.solve(self._q, self._l, self._u, budget)
        if solution is None:
            return None
        n = self.config.horizon
        states, jerks = np.empty((n + 1, 3)), np.empty(n)
        c = self.config
        slack, mode, intrusion, intrusion_ahead = plan_within_bounds(
            self._start, solution[self._nx: self._nx + n], c.step, self._l[self._rows_accel],
            self._u[self._rows_accel], self._u[self._rows_jerk], self._stop, self._follow, self._ahead, c.headway,
            c.standstill_gap - c.emergency_gap, states, jerks)
        return MPCPlan(states[:, 0], states[:, 1], states[:, 2], jerks, slack, MODES[mode],
                       TIERS[tier], iterations, intrusion, converged, intrusion_ahead)

    def fallback(self, speed: float, accel: float) -> MPCPlan:
        """Braking to rest at the comfort bound, the jerk bound permitting: the plan when OSQP gives none."""
        c, n, h = self.config, self.config.horizon, self.config.step
        s, v, a = np.zeros(n + 1), np.zeros(n + 1), np.zeros(n + 1)
        j = np.zeros(n)
        v[0], a[0] = speed, accel
        for k in range(n):
            target = c.accel_min if v[k] > 0.0 else 0.0
            j[k] = min(max((target - a[k]) / h, -c.jerk_max), c.jerk_max)
            a[k + 1] = a[k] + j[k] * h
            v[k + 1] = max(v[k] + a[k] * h + 0.5 * j[k] * h * h, 0.0)
            s[k + 1] = s[k] + 0.5 * (v[k] + v[k + 1]) * h
        return MPCPlan(s, v, a, j, math.inf, "stop", "fallback", 0, converged=False)


@inline
def rear_at(gap: float, speed: float, accel: float, t: float) -> float:
    """[m] a leader's rear bumper (the ego's front now = 0) t [s] from now: `gap` [m] now, at `speed` [m/s] (at least
    0) with constant `accel` [m/s^2], never reversing (it stands once it has braked to rest)."""
    v = max(speed, 0.0)
    if accel < 0.0:
        t = min(t, v / -accel)
    return gap + v * t + 0.5 * accel * t * t


@jit
def rear_positions(gap: float, speed: float, accel: float, times: np.ndarray) -> np.ndarray:
    """`rear_at` at each of `times` [s]."""
    out = np.empty(len(times))
    for k in range(len(times)):
        out[k] = rear_at(gap, speed, accel, times[k])
    return out


@jit
def fold_leader(gap, speed, accel, times, standstill_gap, follow, ahead, to_ahead):
    """The follow bounds of a leader (`rear_at` at `times` [s], less `standstill_gap` [m]) folded into `follow` [m]
    (the least of each step's bounds), and into `ahead` where `to_ahead` (a leader ahead, not alongside)."""
    for k in range(len(times)):
        bound = rear_at(gap, speed, accel, times[k]) - standstill_gap
        follow[k] = min(follow[k], bound)
        if to_ahead:
            ahead[k] = min(ahead[k], bound)


@jit
def plan_within_bounds(initial, jerks, h, a_min, a_max, j_max, stop, follow, ahead, headway, near, states, out):
    """A solution's jerks moved onto the hard bounds they exceed within OSQP's tolerance (about 1e-3 of the
    problem's scale) and the states (s, v, a) integrated exactly from `initial` into `states` (N + 1, 3), the jerks
    into `out` (N,): a plan that meets its bounds and its dynamics to rounding. Returns its largest violation [m]
    of the position constraints s_k <= stop_k and s_k + headway v_k <= follow_k; its mode (an index of MODES: the
    constraint within BINDING of binding at the earliest step; cruise if none); and its intrusion [m]: how far it
    passes a stop point or comes nearer than follow_k + `near` (a leader's rear less the emergency gap), counted
    from where the car is when it is past either already (standing there is no intrusion); and the same intrusion
    with `ahead` (the follow bounds of the leaders ahead only) for `follow`."""
    s, v, a = initial[0], initial[1], initial[2]
    states[0, 0], states[0, 1], states[0, 2] = s, v, a
    slack, mode, intrusion, intrusion_ahead = 0.0, 0, -np.inf, -np.inf
    for k in range(len(jerks)):
        j = min(max(jerks[k], -j_max), j_max)
        j = min(max(j, (a_min - a) / h), (a_max - a) / h)
        s, v, a = s + v * h + a * h * h / 2 + j * h * h * h / 6, v + a * h + j * h * h / 2, a + j * h
        out[k] = j
        states[k + 1, 0], states[k + 1, 1], states[k + 1, 2] = s, v, a
        stop_room, follow_room = stop[k] - s, follow[k] - s - headway * v
        slack = max(slack, -stop_room, -follow_room)
        # what the plan itself moves into (a point already behind the bumper counts from where the car is)
        intrusion = max(intrusion, s - max(stop[k], 0.0), s - max(follow[k] + near, 0.0))
        intrusion_ahead = max(intrusion_ahead, s - max(stop[k], 0.0), s - max(ahead[k] + near, 0.0))
        if mode == 0 and min(stop_room, follow_room) < BINDING:
            mode = 2 if stop_room <= follow_room else 1
    return slack, mode, intrusion - INTRUSION_TOLERANCE, intrusion_ahead - INTRUSION_TOLERANCE
