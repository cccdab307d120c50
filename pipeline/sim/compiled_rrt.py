"""OMPL's RRT-Connect compiled together with the sphere checker's scan: the same search as
``og.RRTConnect`` (OMPL 2.0) checked by a :class:`pipeline.sim.fast_check.SphereChecker`,
without a call from C++ into Python for every check.

Why.  With the sphere checker, most of a planning call's time was the crossings between
OMPL and Python (a state check or an edge check is a Python call from OMPL, then numpy
arrays, the budget, the checker and the compiled scan; docs/results.md), not the checks.
Here the whole loop is one compiled function that returns to Python only where Python
must act: a configuration only pybullet can settle, a wrist-table cell never computed,
the termination condition (every :data:`CLOCK_CHECKS` checks or :data:`CLOCK_ITERATIONS`
iterations, and whenever the budget or the pause's allowance may be reached), a tree
outgrowing its arrays, and the end.

The same numbers, not similar ones.  Each step below is OMPL's, operation for operation:

* Random numbers (``ompl/util/src/RandomNumbers.cpp``).  ``RNG.setSeed(s)`` seeds the
  process's seed generator, a ``std::ranlux24_base``; every RNG object OMPL makes draws its
  own seed from it (``std::uniform_int_distribution<int>(1, 10**9)``, libstdc++'s
  algorithm) and runs a ``std::mt19937``.  A call makes :data:`SAMPLER_DRAW` such objects
  after the seed before the state sampler, whose seed is therefore the next draw (found by
  matching OMPL's samples; the tests compare whole planning calls).  A uniform draw is
  libstdc++'s ``generate_canonical`` of two 32-bit outputs, scaled as
  ``RNG::uniformReal`` does.
* The search (``RRTConnect::solve`` and ``growTree``): the trees alternate, the goal tree
  gets the goal state in the first iteration, a sample is approached by at most ``range``
  (``interpolate``, ``equalStates``), a goal-tree extension checks the new state and then
  the edge back, a tree that advanced is connected to the other until trapped or reached.
  Distances are ``RealVectorStateSpace::distance``'s sum in coordinate order.  Nearest
  neighbours are found by a linear scan; OMPL's GNAT finds the same nearest state except
  between two states at exactly the same distance, which the tests have not met.
* The shortcutting that follows (:func:`shortcut`): numpy's pairs of waypoints drawn
  from the same 32-bit words as :class:`pipeline.planning.shortcut.Pairs`, the same edge
  checks, the same shorter path.
* Checks and their count (:class:`pipeline.planning.base.Budget` over the checker): the
  same rows in the same order, the same calls to pybullet (through the checker's own
  ``_ask``), the same counts.  The checker's memos of settled states and refuted edges only
  spare scans, so this loop simply scans again.

The wall-clock cap is looked at every :data:`CLOCK_CHECKS` checks rather than every
iteration, so a call can overrun it by that many checks (a call that times out is not
reproducible either way).
"""

from __future__ import annotations

import math
import types

import numpy as np
from numba import njit

from pipeline.sim import collide

#: the first 16 hex digits of the SHA-256 of each module file in pipeline/sim whose compiled
#: functions the kernels here call: numba links them into this module's cached code but
#: checks only this file's stamp when it loads that cache, so a change to one of them must
#: change this file too (tests/test_kernel_cache.py checks these digests)
LINKED = {"collide.py": "5388238a9e82e474"}

#: the RNG objects OMPL makes in a call after the seed and before the state sampler (whose
#: seed is the seed generator's next draw), counted by matching OMPL's samples
#: (tests/test_compiled_rrt.py)
SAMPLER_DRAW = 6
_NEVER = 1 << 62
#: checks, and iterations, after which the search looks at the termination condition
#: again (its clock: the wall-clock cap), besides whenever the budget or the pause's
#: allowance may be reached
CLOCK_CHECKS = 256
CLOCK_ITERATIONS = 1024

# control words (``ctl``)
_PC, _N, _START_TREE, _HAS_GOAL, _GT, _GSTART, _TGI_START, _NM, _REACH, _DX, _PHASE = range(11)
_ADDED, _XMOTION, _USED, _CK, _CK_STEPS, _CK_K, _CK_M, _CK_WAIT, _ROWS, _PROVED = range(11, 21)
_SM, _GM, _CLOCK = 21, 22, 23
_CTL = 24

# the shortcutting's own words of ``ctl``: the attempt, the next random word, the pair
_ATTEMPT, _WORD, _I, _J = _PC, _ADDED, _NM, _XMOTION

# program counters
_AT_START, _AT_ITERATION, _AT_GOAL, _AT_SAMPLE, _AT_GROW, _AT_GROW_STATE, _AT_GROW_EDGE = range(7)
# check kinds and what a check waits for
_NONE, _STATE, _EDGE = 0, 1, 2
_WAIT_EXACT, _WAIT_CELLS = 1, 2
# a check's outcome
_FREE, _HIT, _NEED_EXACT, _NEED_CELLS = 0, 1, 2, 3
# growTree's
_TRAPPED, _ADVANCED, _REACHED = 0, 1, 2

#: RealVectorStateSpace::equalStates' tolerance per coordinate
_EQUAL = 2.0 * float(np.finfo(np.float64).eps)

#: what :func:`_advance` returns
ASK_STOP, ASK_EXACT, ASK_CELLS, SOLVED, NO_START, NO_GOAL, ASK_ROOM, ASK_WORDS = range(8)
#: the trees' first capacity (doubled as they grow)
NODES = 1024


# -- OMPL's random numbers ------------------------------------------------------------------
@njit(cache=True)
def _ranlux(x, st):  # pragma: no cover (compiled)
    """std::ranlux24_base's next output (x: its 24 words, st: index and carry)."""
    p, carry = st[0], st[1]
    ps = p - 10
    if ps < 0:
        ps += 24
    if x[ps] >= x[p] + carry:
        xi = x[ps] - x[p] - carry
        carry = 0
    else:
        xi = (1 << 24) - x[p] - carry + x[ps]
        carry = 1
    x[p] = xi
    p += 1
    if p >= 24:
        p = 0
    st[0], st[1] = p, carry
    return xi


@njit(cache=True)
def _seed_draw(x, st):  # pragma: no cover (compiled)
    """libstdc++'s uniform_int_distribution<int>(1, 10**9) over the 24-bit generator: a
    draw in [0, 59] (by division, rejecting the top) times 2**24 plus one more output,
    rejected above the range."""
    urange = 999999999
    scaling = ((1 << 24) - 1) // 60
    past = 60 * scaling
    while True:
        r = _ranlux(x, st)
        while r >= past:
            r = _ranlux(x, st)
        tmp = (1 << 24) * (r // scaling)
        ret = tmp + _ranlux(x, st)
        if ret <= urange:
            return ret + 1


@njit(cache=True)
def sampler_seed(first):  # pragma: no cover (compiled)
    """The state sampler's seed after ``RNG.setSeed(first)`` (:data:`SAMPLER_DRAW`)."""
    x = np.empty(24, dtype=np.int64)
    lcg = first if first != 0 else 19780503
    for i in range(24):
        lcg = (40014 * lcg) % 2147483563
        x[i] = lcg % (1 << 24)
    st = np.zeros(2, dtype=np.int64)
    st[1] = 1 if x[23] == 0 else 0
    seed = 0
    for _ in range(SAMPLER_DRAW + 1):
        seed = _seed_draw(x, st)
    return seed


@njit(cache=True)
def mt_seed(seed, mt):  # pragma: no cover (compiled)
    """std::mt19937(seed) into mt (624 words, then the index)."""
    mt[0] = seed & 0xFFFFFFFF
    for i in range(1, 624):
        prev = mt[i - 1]
        mt[i] = (1812433253 * (prev ^ (prev >> 30)) + i) & 0xFFFFFFFF
    mt[624] = 624


@njit(cache=True)
def mt_next(mt):  # pragma: no cover (compiled)
    """std::mt19937's next 32-bit output."""
    if mt[624] >= 624:
        for i in range(624):
            y = (mt[i] & 0x80000000) | (mt[(i + 1) % 624] & 0x7FFFFFFF)
            v = mt[(i + 397) % 624] ^ (y >> 1)
            if y & 1:
                v ^= 0x9908B0DF
            mt[i] = v
        mt[624] = 0
    y = mt[mt[624]]
    mt[624] += 1
    y ^= y >> 11
    y ^= (y << 7) & 0x9D2C5680
    y ^= (y << 15) & 0xEFC60000
    y ^= y >> 18
    return y


@njit(cache=True)
def uniform01(mt):  # pragma: no cover (compiled)
    """libstdc++'s generate_canonical<double, 53> of mt19937: two outputs, low first."""
    s = float(mt_next(mt))
    s += float(mt_next(mt)) * 4294967296.0
    r = s / 18446744073709551616.0
    if r >= 1.0:
        r = np.nextafter(1.0, 0.0)
    return r


# -- the search -------------------------------------------------------------------------------
@njit(cache=True)
def _distance(a, b):  # pragma: no cover (compiled)
    s = 0.0
    for i in range(a.shape[0]):
        diff = a[i] - b[i]
        s += diff * diff
    return math.sqrt(s)


@njit(cache=True)
def _nearest(X, tr, n, tree, q):  # pragma: no cover (compiled)
    best, at = np.inf, -1
    for i in range(n):
        if tr[i] == tree:
            d = _distance(X[i], q)
            if d < best:
                best, at = d, i
    return at


@njit(cache=True)
def _put(dst, src):  # pragma: no cover (compiled)
    """``dst[:] = src`` for two 1-d arrays of one length, as a loop: numba's slice
    assignment compiles the formatting of its shape-mismatch error, seconds of a cold
    compile."""
    for i in range(src.shape[0]):
        dst[i] = src[i]


@njit(cache=True)
def _add(ctl, X, par, tr, q, parent, tree):  # pragma: no cover (compiled)
    n = ctl[_N]
    _put(X[n], q)
    par[n], tr[n] = parent, tree
    ctl[_N] = n + 1
    return n


@njit(cache=True)
def _begin(ctl, ca, cb, kind, a, b, limit):  # pragma: no cover (compiled)
    """Start a check (the budget's ``states_free`` of one state a, or ``edge_free`` a→b);
    False: the budget is spent, the check refused uncounted."""
    if ctl[_USED] >= limit:
        return False
    _put(ca, a)
    _put(cb, b)
    ctl[_CK], ctl[_CK_WAIT], ctl[_CK_K] = kind, 0, 0
    return True


# _scan and _run_check are inlined into their callers (numba's IR inlining): a compiled
# function that calls another links the callee's code into its own and optimises it all
# again, so each extra layer above collide._scan cost seconds of a cold compile
@njit(cache=True, inline="always")
def _scan(kind, a, b, resolution, limit, start, geo):  # pragma: no cover (compiled)
    """:func:`pipeline.sim.collide.edge_first`'s scan.  Its empty frames are made here, not
    taken from the module's globals: numba types a global array as a read-only one, and
    would compile the whole scan once more for it.  Callers pass ``limit`` and ``start``
    as int64 variables, never as integer constants: numba types a constant argument as a
    literal and compiles this function (and links the scan into it) once per literal."""
    return collide._scan(kind, np.empty((0, 1, 3, 4)), np.zeros(0, dtype=np.bool_), a, b,
                         resolution, limit, start, *geo)


@njit(cache=True, inline="always")
def _run_check(ctl, ca, cb, resolution, limit, answer, kind, geo):  # pragma: no cover
    """Go on with the check begun by :func:`_begin` (``answer``: pybullet's, 1 collides,
    for the row it waits for): _FREE, _HIT, or what it needs from Python (the row's or the
    cells' position in ``ctl``).  A finished check adds its rows to the budget."""
    wait = ctl[_CK_WAIT]
    ctl[_CK_WAIT] = 0
    if ctl[_CK] == _STATE:  # SphereChecker._one: settle by the scan, else ask pybullet
        if wait == _WAIT_EXACT:
            hit = answer != 0
        else:
            _, k, proved = _scan(kind, ca, ca, 1.0, np.int64(1), np.int64(0), geo)
            if k < 0:
                ctl[_CK_WAIT] = _WAIT_CELLS
                return _NEED_CELLS
            if k < 1 and not proved:
                ctl[_CK_WAIT] = _WAIT_EXACT
                return _NEED_EXACT
            hit = k < 1
            if hit:
                ctl[_PROVED] += 1
        ctl[_CK] = _NONE
        ctl[_ROWS] += 1
        ctl[_USED] += 1
        return _HIT if hit else _FREE
    # SphereChecker.motion within the budget's rows left
    rows = limit - ctl[_USED]
    k = ctl[_CK_K]
    if wait == _WAIT_EXACT:
        if answer != 0:
            ctl[_CK] = _NONE
            ctl[_USED] += k + 1
            return _HIT
        start = k + 1
    elif wait == _WAIT_CELLS:
        start = k
    else:
        start = 0
    steps, k, proved = _scan(kind, ca, cb, resolution, rows, start, geo)
    if wait == 0:  # the motion's first scan: its rows count once
        ctl[_ROWS] += min(steps, rows)
    m = min(steps, rows)
    ctl[_CK_STEPS], ctl[_CK_M] = steps, m
    if k < m:
        if k < 0:
            ctl[_CK_K], ctl[_CK_WAIT] = -1 - k, _WAIT_CELLS
            return _NEED_CELLS
        if proved:
            ctl[_PROVED] += 1
            ctl[_CK] = _NONE
            ctl[_USED] += k + 1
            return _HIT
        ctl[_CK_K], ctl[_CK_WAIT] = k, _WAIT_EXACT
        return _NEED_EXACT
    ctl[_CK] = _NONE
    ctl[_USED] += m
    return _FREE if m >= steps else _HIT


@njit(cache=True)
def _advance(ctl, X, par, tr, rs, xs, ca, cb, mt, lower, upper, start, goal, reach_max,
             resolution, limit, pause, ptc_false, answer, kind, geo):  # pragma: no cover
    """Run the search from where ``ctl`` left it until Python must act (the return value:
    ``ASK_*``) or it ends (``SOLVED``, ``NO_START``, ``NO_GOAL``).  ``ptc_false``: Python
    has just found the termination condition false for the iteration about to start.  A
    check begun is run at the top of the loop, then the step that began it takes its
    outcome."""
    d = lower.shape[0]
    clock = CLOCK_ITERATIONS
    while True:
        out = -1
        if ctl[_CK] != _NONE:
            out = _run_check(ctl, ca, cb, resolution, limit, answer, kind, geo)
            answer = 0
            if out == _NEED_EXACT:
                return ASK_EXACT
            if out == _NEED_CELLS:
                return ASK_CELLS
        pc = ctl[_PC]
        if pc == _AT_START or pc == _AT_GOAL:
            # pis_.nextStart() before the loop, pis_.nextGoal(ptc) in its first iteration:
            # the state checked, then the root of its tree
            root = 0 if pc == _AT_START else 1
            q = start if root == 0 else goal
            if out < 0:
                if _begin(ctl, ca, cb, _STATE, q, q, limit):
                    continue
                return NO_START if root == 0 else NO_GOAL
            if out == _HIT:
                return NO_START if root == 0 else NO_GOAL
            _add(ctl, X, par, tr, q, -1, root)
            ctl[_HAS_GOAL] = root
            ctl[_PC] = _AT_ITERATION if root == 0 else _AT_SAMPLE
        elif pc == _AT_ITERATION:  # while (!ptc)
            if not ptc_false:
                if (ctl[_USED] >= limit or ctl[_USED] >= pause or ctl[_USED] >= ctl[_CLOCK]
                        or clock == 0):
                    ctl[_CLOCK] = ctl[_USED] + CLOCK_CHECKS
                    return ASK_STOP
            ptc_false = False
            clock -= 1
            ctl[_GT] = 0 if ctl[_START_TREE] else 1
            ctl[_TGI_START] = ctl[_START_TREE]
            ctl[_START_TREE] = 1 - ctl[_START_TREE]
            ctl[_PC] = _AT_SAMPLE if ctl[_HAS_GOAL] else _AT_GOAL
        elif pc == _AT_SAMPLE:  # sampler_->sampleUniform(rstate), then growTree(tree)
            for i in range(d):
                rs[i] = (upper[i] - lower[i]) * uniform01(mt) + lower[i]
            ctl[_PHASE], ctl[_GSTART] = 1, ctl[_TGI_START]
            ctl[_PC] = _AT_GROW
        else:
            grown = -1
            if pc == _AT_GROW:
                if ctl[_N] == X.shape[0]:  # no room for the state it may add: Python makes some
                    return ASK_ROOM
                nm = _nearest(X, tr, ctl[_N], ctl[_GT], rs)
                ctl[_NM] = nm
                dist = _distance(X[nm], rs)
                ctl[_REACH], ctl[_DX] = 1, 0
                if dist > reach_max:
                    t = reach_max / dist
                    same = True
                    for i in range(d):
                        xs[i] = X[nm, i] + (rs[i] - X[nm, i]) * t
                        same = same and abs(X[nm, i] - xs[i]) <= _EQUAL
                    ctl[_REACH], ctl[_DX] = 0, 1
                    if same:
                        grown = _TRAPPED
                if grown < 0:
                    dstate = xs if ctl[_DX] else rs
                    if ctl[_GSTART]:
                        ctl[_PC] = _AT_GROW_EDGE
                        if _begin(ctl, ca, cb, _EDGE, X[nm], dstate, limit):
                            continue
                    else:
                        ctl[_PC] = _AT_GROW_STATE
                        if _begin(ctl, ca, cb, _STATE, dstate, dstate, limit):
                            continue
                    grown = _TRAPPED
            elif pc == _AT_GROW_STATE:  # isValid(dstate), then the edge back to nmotion
                if out == _HIT:
                    grown = _TRAPPED
                else:
                    dstate = xs if ctl[_DX] else rs
                    ctl[_PC] = _AT_GROW_EDGE
                    if _begin(ctl, ca, cb, _EDGE, dstate, X[ctl[_NM]], limit):
                        continue
                    grown = _TRAPPED
            elif out == _HIT:  # _AT_GROW_EDGE
                grown = _TRAPPED
            else:
                dstate = xs if ctl[_DX] else rs
                ctl[_XMOTION] = _add(ctl, X, par, tr, dstate, ctl[_NM], ctl[_GT])
                grown = _REACHED if ctl[_REACH] else _ADVANCED
            # what solve() does with growTree's answer
            if ctl[_PHASE] == 1:
                if grown == _TRAPPED:
                    ctl[_PC] = _AT_ITERATION
                    continue
                ctl[_ADDED] = ctl[_XMOTION]
                if grown != _REACHED:
                    _put(rs, xs)
                ctl[_TGI_START] = ctl[_START_TREE]
                ctl[_GT] = 0 if ctl[_START_TREE] else 1
                ctl[_GSTART], ctl[_PHASE], ctl[_PC] = ctl[_TGI_START], 2, _AT_GROW
                continue
            if grown == _ADVANCED:
                ctl[_PC] = _AT_GROW
                continue
            if grown == _TRAPPED:
                ctl[_PC] = _AT_ITERATION
                continue
            sm = ctl[_XMOTION] if ctl[_TGI_START] else ctl[_ADDED]
            gm = ctl[_ADDED] if ctl[_TGI_START] else ctl[_XMOTION]
            if par[sm] >= 0:  # one step back: no state twice on the path
                sm = par[sm]
            else:
                gm = par[gm]
            ctl[_SM], ctl[_GM] = sm, gm
            return SOLVED


class _Checks:
    """The Python side of a kernel's checks on ``budget.robot``'s checker: the scan's
    arguments, the budget's and the checker's counts kept in step with ``ctl``, and the
    pybullet answers and wrist-table cells a kernel asks for (``ca``, ``cb``: its check's
    end states)."""

    def __init__(self, budget, ctl, ca, cb):
        self.budget, self.ctl, self.ca, self.cb = budget, ctl, ca, cb
        self.checker = budget.robot.checker
        self.kind, psi, step, self.table, chain, packed, memo = self.checker.scan_args()
        self._fixed = (psi, step, chain, packed, memo)

    def run(self, kernel, *args) -> int:
        """``kernel(*args, kind, geometry)`` with the budget's count in ``ctl``; the counts
        it made added to the budget's and the checker's."""
        ctl, stats = self.ctl, self.checker.stats
        psi, step, chain, packed, memo = self._fixed
        cells = self.table.state if self.table is not None else collide._NO_CELLS
        rows, proved = ctl[_ROWS], ctl[_PROVED]
        ctl[_USED] = self.budget.used
        out = kernel(*args, self.kind,
                     (collide.SEGMENT, psi, step, cells, *chain, *packed, *memo))
        self.budget.used = int(ctl[_USED])
        stats["rows"] += int(ctl[_ROWS] - rows)
        stats["proved"] += int(ctl[_PROVED] - proved)
        return out

    def serve(self, out: int) -> int:
        """Python's part of ``ASK_EXACT`` (pybullet's answer for the row the check waits
        for, as the checker makes it: 1 collides) or ``ASK_CELLS`` (the cells computed;
        0)."""
        ctl, checker, ca, cb = self.ctl, self.checker, self.ca, self.cb
        state = ctl[_CK] == _STATE
        steps, k = int(ctl[_CK_STEPS]), int(ctl[_CK_K])
        if out == ASK_EXACT:
            return int(checker._ask(ca.copy() if state else checker.row(ca, cb, steps, k)))
        if state:
            self.table.uncertain(ca[None])
        else:
            checker.wrist_cells(ca, cb, steps, k, int(ctl[_CK_M]))
        return 0


@njit(cache=True)
def _path_rows(sm, gm, par):  # pragma: no cover (compiled)
    """The rows of the solution path: ``sm``'s ancestors from the start root down to
    ``sm``, then ``gm`` up to the goal root (compiled: walking the parents in Python cost
    about 1 % of a pick_place entry)."""
    head = 0
    i = sm
    while i >= 0:
        head += 1
        i = par[i]
    tail = 0
    i = gm
    while i >= 0:
        tail += 1
        i = par[i]
    out = np.empty(head + tail, dtype=np.int64)
    i = sm
    for k in range(head - 1, -1, -1):
        out[k] = i
        i = par[i]
    i = gm
    for k in range(head, head + tail):
        out[k] = i
        i = par[i]
    return out


class CompiledRRTConnect:
    """One planning call's search (:class:`pipeline.planning.ompl_adapter._Problem`'s
    interface: :meth:`solve` until a path or the termination condition, again after a
    pause).  ``budget.robot`` must be a robot whose checks are a scanning
    :class:`~pipeline.sim.fast_check.SphereChecker`'s (:func:`applies`); ``reach``: the
    planner's range (0: OMPL's default); ``first_seed``: the seed OMPL's would be given
    (:func:`pipeline.planning.ompl_adapter.ompl_seed`)."""

    def __init__(self, lower, upper, start, goal, budget, reach: float, resolution: float,
                 first_seed: int):
        d = len(lower)
        self.lower = np.ascontiguousarray(lower, dtype=float)
        self.upper = np.ascontiguousarray(upper, dtype=float)
        self.start = np.ascontiguousarray(start, dtype=float)
        self.goal = np.ascontiguousarray(goal, dtype=float)
        self.budget, self.resolution = budget, float(resolution)
        if reach <= 0:  # SelfConfig: 0.2 x the space's extent, summed in coordinate order
            extent = 0.0
            for lo, hi in zip(self.lower.tolist(), self.upper.tolist(), strict=True):
                extent += (hi - lo) * (hi - lo)
            reach = math.sqrt(extent) * 0.2
        self.reach = float(reach)
        self.X = np.empty((NODES, d))
        self.par = np.empty(NODES, dtype=np.int64)
        self.tr = np.empty(NODES, dtype=np.int8)
        #: what ended the search for good (OMPL's answer to every later ``solve``), or None
        self._ended: int | None = None
        self.rs, self.xs, self.ca, self.cb = (np.empty(d) for _ in range(4))
        self.ctl = np.zeros(_CTL, dtype=np.int64)
        self.ctl[_START_TREE] = 1
        self.ctl[_CLOCK] = budget.used + CLOCK_CHECKS
        self.mt = np.empty(625, dtype=np.int64)
        mt_seed(sampler_seed(first_seed), self.mt)

    def solve(self, stop, pause_at: int | None = None) -> np.ndarray | None:
        """Search until a path (returned) or ``stop()`` (None); ``pause_at``: the budget's
        count at which ``stop()`` pauses the try, if it does."""
        budget, ctl = self.budget, self.ctl
        if self._ended is not None:
            return self._refused(stop)
        if not applies(budget.robot):
            raise RuntimeError("compiled RRT-Connect: the robot was rebound to one whose "
                               "checks are not a scanning sphere checker's")
        checks = _Checks(budget, ctl, self.ca, self.cb)
        pause = _NEVER if pause_at is None else int(pause_at)
        ptc_false, answer = False, 0
        while True:
            out = checks.run(_advance, ctl, self.X, self.par, self.tr, self.rs, self.xs,
                             self.ca, self.cb, self.mt, self.lower, self.upper, self.start,
                             self.goal, self.reach, self.resolution, budget.limit, pause,
                             ptc_false, answer)
            ptc_false, answer = False, 0
            if out == ASK_STOP:
                if stop():
                    return None
                ptc_false = True
            elif out == ASK_EXACT or out == ASK_CELLS:
                answer = checks.serve(out)
            elif out == ASK_ROOM:
                self.X = np.concatenate([self.X, np.empty_like(self.X)])
                self.par = np.concatenate([self.par, np.empty_like(self.par)])
                self.tr = np.concatenate([self.tr, np.empty_like(self.tr)])
            elif out == SOLVED:
                return self._path()
            else:
                self._ended = out
                return self._refused(stop)

    def _refused(self, stop) -> None:
        """OMPL's answer once the start or the goal state was refused (each is checked
        once, in the first ``solve``): no path; with the goal refused it waits for the
        termination condition, which only the wall-clock cap then makes true."""
        if self._ended == NO_GOAL and not stop():
            self.budget.timed_out = True
        return None

    def _path(self) -> np.ndarray:
        """Start root … ``_SM``, then ``_GM`` … goal root (RRTConnect's solution path)."""
        return self.X[_path_rows(self.ctl[_SM], self.ctl[_GM], self.par)]

    def forget_approximations(self) -> None:
        """Nothing to forget: only an exact path is ever kept."""


# -- shortcutting -----------------------------------------------------------------------------
@njit(cache=True)
def _bounded(words, pos, r):  # pragma: no cover (compiled)
    """numpy's bounded draw in [0, r] (Lemire's, :class:`pipeline.planning.shortcut.Pairs`)
    from 32-bit ``words`` at ``pos``: (value, next pos), or (-1, pos) when they run out."""
    excl = r + 1
    if pos >= words.shape[0]:
        return -1, pos
    m = words[pos] * excl
    pos += 1
    if m & 0xFFFFFFFF < excl:
        threshold = (0xFFFFFFFF - r) % excl
        while m & 0xFFFFFFFF < threshold:
            if pos >= words.shape[0]:
                return -1, pos
            m = words[pos] * excl
            pos += 1
    return m >> 32, pos


@njit(cache=True)
def _shortcut(ctl, path, words, ca, cb, resolution, limit, attempts, answer, kind,
              geo):  # pragma: no cover (compiled)
    """:func:`pipeline.planning.shortcut.shortcut` from where ``ctl`` left it: the path's
    first ``ctl[_N]`` rows (shortened in place), attempt ``ctl[_ATTEMPT]``, word
    ``ctl[_WORD]`` next.  Returns SOLVED at the end, ASK_EXACT / ASK_CELLS for an edge
    check, ASK_WORDS when the words ran out (Python adds more; the draw starts again)."""
    while True:
        if ctl[_CK] != _NONE:  # an edge check under way
            out = _run_check(ctl, ca, cb, resolution, limit, answer, kind, geo)
            if out == _NEED_EXACT:
                return ASK_EXACT
            if out == _NEED_CELLS:
                return ASK_CELLS
            if out == _FREE:  # path[:i + 1] + path[j:]
                i, j, n = ctl[_I], ctl[_J], ctl[_N]
                for r in range(j, n):
                    _put(path[i + 1 + r - j], path[r])
                ctl[_N] = n - (j - i - 1)
        if ctl[_ATTEMPT] >= attempts or ctl[_N] < 3 or ctl[_USED] >= limit:
            return SOLVED
        n, pos = ctl[_N], ctl[_WORD]
        v1 = 0
        if n > 2:
            v1, pos = _bounded(words, pos, n - 2)
        v2 = -1
        if v1 >= 0:
            v2, pos = _bounded(words, pos, n - 1)
        if v2 < 0 or pos >= words.shape[0]:
            return ASK_WORDS
        pos += 1  # the shuffle of the pair
        if v2 == v1:
            v2 = n - 1
        i, j = min(v1, v2), max(v1, v2)
        ctl[_ATTEMPT] += 1
        ctl[_WORD] = pos
        if j - i < 2:
            continue
        ctl[_I], ctl[_J] = i, j
        _begin(ctl, ca, cb, _EDGE, path[i], path[j], limit)


def shortcut(path: np.ndarray, budget, pairs, resolution: float, attempts: int) -> np.ndarray:
    """:func:`pipeline.planning.shortcut.shortcut` compiled with the checker's scan: the same
    pairs (``pairs``' words: numpy's draws), checks and path; ``pairs`` is left as after
    those draws (its ``used``)."""
    path = np.array(path, dtype=float)
    ctl = np.zeros(_CTL, dtype=np.int64)
    ctl[_N], ctl[_WORD] = len(path), pairs.used
    ca, cb = np.empty(path.shape[1]), np.empty(path.shape[1])
    checks = _Checks(budget, ctl, ca, cb)
    resolution, answer = float(resolution), 0
    while True:
        out = checks.run(_shortcut, ctl, path, np.array(pairs.words, dtype=np.int64), ca, cb,
                         resolution, budget.limit, attempts, answer)
        answer = 0
        if out == ASK_WORDS:
            pairs.more()
        elif out == ASK_EXACT or out == ASK_CELLS:
            answer = checks.serve(out)
        else:
            pairs.used = int(ctl[_WORD])
            return path[: ctl[_N]]


def warm_up(checker) -> None:
    """Load (or compile) :func:`_advance` with the argument types :meth:`CompiledRRTConnect.solve`
    passes for ``checker`` (a scanning sphere checker): a search whose budget is spent
    before its first check."""
    robot = types.SimpleNamespace(checker=checker, check=checker.__call__,
                                  check_motion=checker.motion)
    budget = types.SimpleNamespace(robot=robot, limit=0, used=0, timed_out=False)
    d = 3
    CompiledRRTConnect(np.zeros(d), np.ones(d), np.zeros(d), np.ones(d), budget, 0.0, 0.01,
                       1).solve(lambda: True)
    _path_rows(np.int64(0), np.int64(1), np.full(2, -1, dtype=np.int64))
    pairs = types.SimpleNamespace(words=[0] * 8, used=0)
    shortcut(np.zeros((3, d)), budget, pairs, 0.01, 1)


def applies(robot) -> bool:
    """Whether :class:`CompiledRRTConnect` can plan for ``robot``: its checks and edge
    checks are a scanning sphere checker's own methods."""
    checker = getattr(robot, "checker", None)
    scan_args = getattr(checker, "scan_args", None)
    return (scan_args is not None and checker._motion is not None
            and getattr(robot, "check", None) == checker.__call__
            and getattr(robot, "check_motion", None) == checker.motion)
