"""The pieces of an L-BFGS minimiser that run inside numba, so that OLNG's pose search
(`pose.minimise`) is one compiled loop around its energy instead of scipy's L-BFGS-B
driver, whose Python side cost about 0.2 ms an iteration around an energy of a few
microseconds.

The loop follows L-BFGS-B (Byrd, Lu, Nocedal and Zhu 1995, "A limited memory algorithm
for bound constrained optimization"; Zhu, Byrd, Lu and Nocedal 1997, "Algorithm 778")
as scipy runs it on a problem without bounds, so that it takes the same steps:

- the direction −H g from the last `MEMORY` pairs (s, y) by the two-loop recursion
  with H₀ = (sᵀy / yᵀy) I (without bounds, L-BFGS-B's Cauchy point and subspace step
  are this quasi-Newton step); the first direction, and the first after a restart,
  is −g;
- the step from Moré and Thuente's line search (1994, "Line search algorithms with
  guaranteed sufficient decrease"; MINPACK-2's dcsrch and dcstep, ported below) with
  L-BFGS-B's constants: ftol 1e-3, gtol 0.9, xtol 0.1, the first trial step 1/‖d‖ on
  the first iteration and 1 after, at most `MAX_TRIALS` evaluations a search;
- a pair is kept only when sᵀy > ε_mach · (−gᵀs); a failed search (no descent, or too
  many trials) restores the last point and restarts from −g, or ends the run when the
  memory is already empty;
- the stopping rules: max |g| ≤ pgtol, or the relative reduction of f at most
  factr · ε_mach (scipy's ftol, 2.2e-9 by default), or the iteration limit.
"""

from __future__ import annotations

import math

import numba
import numpy as np

MEMORY = 10  # pairs kept (scipy's maxcor)
FTOL = 1e-3  # the line search's sufficient-decrease constant (L-BFGS-B's)
GTOL = 0.9  # its curvature constant
XTOL = 0.1  # its relative width of an acceptable interval
MAX_TRIALS = 20  # evaluations a line search may take before it counts as failed
STEP_MAX = 1e10  # the largest step (L-BFGS-B's without bounds)
REL_REDUCTION = 2.220446049250313e-09  # scipy's default ftol (factr · ε_mach)

# Line-search state slots (`search_start`, `search_step`).
_BRACKT, _STAGE, _GINIT, _GTEST, _GX, _GY, _FINIT, _FX, _FY, _STX, _STY, _STMIN, _STMAX, _WIDTH, _WIDTH1 = range(15)
STATE_SIZE = 15
SEARCH_MORE, SEARCH_DONE = 0, 1  # what `search_step` asks for: another evaluation, or none


@numba.njit(cache=True, nogil=True)
def _dcstep(stx, fx, dx, sty, fy, dy, stp, fp, dp, brackt, stpmin, stpmax):
    """One safeguarded step of Moré and Thuente's search (MINPACK-2 dcstep): the new
    interval (stx, fx, dx), (sty, fy, dy), whether it brackets a minimiser, and the
    next trial step."""
    sgnd = dp * (dx / abs(dx))
    if fp > fx:  # a higher value: the minimum is bracketed
        theta = 3.0 * (fx - fp) / (stp - stx) + dx + dp
        s = max(abs(theta), abs(dx), abs(dp))
        gamma = s * math.sqrt((theta / s) ** 2 - (dx / s) * (dp / s))
        if stp < stx:
            gamma = -gamma
        p = (gamma - dx) + theta
        q = ((gamma - dx) + gamma) + dp
        r = p / q
        stpc = stx + r * (stp - stx)
        stpq = stx + ((dx / ((fx - fp) / (stp - stx) + dx)) / 2.0) * (stp - stx)
        if abs(stpc - stx) < abs(stpq - stx):
            stpf = stpc
        else:
            stpf = stpc + (stpq - stpc) / 2.0
        brackt = True
    elif sgnd < 0.0:  # derivatives of opposite sign: bracketed
        theta = 3.0 * (fx - fp) / (stp - stx) + dx + dp
        s = max(abs(theta), abs(dx), abs(dp))
        gamma = s * math.sqrt((theta / s) ** 2 - (dx / s) * (dp / s))
        if stp > stx:
            gamma = -gamma
        p = (gamma - dp) + theta
        q = ((gamma - dp) + gamma) + dx
        r = p / q
        stpc = stp + r * (stx - stp)
        stpq = stp + (dp / (dp - dx)) * (stx - stp)
        if abs(stpc - stp) > abs(stpq - stp):
            stpf = stpc
        else:
            stpf = stpq
        brackt = True
    elif abs(dp) < abs(dx):  # same sign, the derivative's magnitude falls
        theta = 3.0 * (fx - fp) / (stp - stx) + dx + dp
        s = max(abs(theta), abs(dx), abs(dp))
        gamma = s * math.sqrt(max(0.0, (theta / s) ** 2 - (dx / s) * (dp / s)))
        if stp > stx:
            gamma = -gamma
        p = (gamma - dp) + theta
        q = (gamma + (dx - dp)) + gamma
        r = p / q
        if r < 0.0 and gamma != 0.0:
            stpc = stp + r * (stx - stp)
        elif stp > stx:
            stpc = stpmax
        else:
            stpc = stpmin
        stpq = stp + (dp / (dp - dx)) * (stx - stp)
        if brackt:
            stpf = stpc if abs(stpc - stp) < abs(stpq - stp) else stpq
            if stp > stx:
                stpf = min(stp + 0.66 * (sty - stp), stpf)
            else:
                stpf = max(stp + 0.66 * (sty - stp), stpf)
        else:
            stpf = stpc if abs(stpc - stp) > abs(stpq - stp) else stpq
            stpf = min(stpmax, stpf)
            stpf = max(stpmin, stpf)
    else:  # same sign, the derivative's magnitude does not fall
        if brackt:
            theta = 3.0 * (fp - fy) / (sty - stp) + dy + dp
            s = max(abs(theta), abs(dy), abs(dp))
            gamma = s * math.sqrt((theta / s) ** 2 - (dy / s) * (dp / s))
            if stp > sty:
                gamma = -gamma
            p = (gamma - dp) + theta
            q = ((gamma - dp) + gamma) + dy
            r = p / q
            stpf = stp + r * (sty - stp)
        elif stp > stx:
            stpf = stpmax
        else:
            stpf = stpmin
    if fp > fx:
        sty, fy, dy = stp, fp, dp
    else:
        if sgnd < 0.0:
            sty, fy, dy = stx, fx, dx
        stx, fx, dx = stp, fp, dp
    return stx, fx, dx, sty, fy, dy, brackt, stpf


@numba.njit(cache=True, nogil=True)
def search_start(f, g, stp, state):
    """A line search from f and its directional derivative g < 0 at step 0, first
    trial step `stp` (MINPACK-2 dcsrch's start)."""
    state[_BRACKT] = 0.0
    state[_STAGE] = 1.0
    state[_FINIT] = f
    state[_GINIT] = g
    state[_GTEST] = FTOL * g
    state[_WIDTH] = STEP_MAX
    state[_WIDTH1] = STEP_MAX / 0.5
    state[_STX] = 0.0
    state[_FX] = f
    state[_GX] = g
    state[_STY] = 0.0
    state[_FY] = f
    state[_GY] = g
    state[_STMIN] = 0.0
    state[_STMAX] = stp + 4.0 * stp


@numba.njit(cache=True, nogil=True)
def search_step(f, g, stp, state):
    """The search's verdict on the trial step `stp` with value f and directional
    derivative g (MINPACK-2 dcsrch): (SEARCH_DONE, stp) when it is accepted (the
    strong Wolfe conditions hold, or rounding or the interval's width stop the
    search), else (SEARCH_MORE, the next trial step)."""
    stpmin, stpmax = 0.0, STEP_MAX
    brackt = state[_BRACKT] != 0.0
    ginit, gtest, finit = state[_GINIT], state[_GTEST], state[_FINIT]
    stmin, stmax = state[_STMIN], state[_STMAX]
    ftest = finit + stp * gtest
    if state[_STAGE] == 1.0 and f <= ftest and g >= 0.0:
        state[_STAGE] = 2.0
    if brackt and (stp <= stmin or stp >= stmax):  # rounding errors prevent progress
        return SEARCH_DONE, stp
    if brackt and stmax - stmin <= XTOL * stmax:
        return SEARCH_DONE, stp
    if stp == stpmax and f <= ftest and g <= gtest:
        return SEARCH_DONE, stp
    if stp == stpmin and (f > ftest or g >= gtest):
        return SEARCH_DONE, stp
    if f <= ftest and abs(g) <= GTOL * (-ginit):  # converged
        return SEARCH_DONE, stp
    stx, fx, gx = state[_STX], state[_FX], state[_GX]
    sty, fy, gy = state[_STY], state[_FY], state[_GY]
    if state[_STAGE] == 1.0 and f <= fx and f > ftest:  # on the modified function
        fm = f - stp * gtest
        fxm = fx - stx * gtest
        fym = fy - sty * gtest
        gm = g - gtest
        gxm = gx - gtest
        gym = gy - gtest
        stx, fxm, gxm, sty, fym, gym, brackt, stp = _dcstep(
            stx, fxm, gxm, sty, fym, gym, stp, fm, gm, brackt, stmin, stmax
        )
        fx = fxm + stx * gtest
        fy = fym + sty * gtest
        gx = gxm + gtest
        gy = gym + gtest
    else:
        stx, fx, gx, sty, fy, gy, brackt, stp = _dcstep(stx, fx, gx, sty, fy, gy, stp, f, g, brackt, stmin, stmax)
    if brackt:
        if abs(sty - stx) >= 0.66 * state[_WIDTH1]:
            stp = stx + 0.5 * (sty - stx)
        state[_WIDTH1] = state[_WIDTH]
        state[_WIDTH] = abs(sty - stx)
        stmin = min(stx, sty)
        stmax = max(stx, sty)
    else:
        stmin = stp + 1.1 * (stp - stx)
        stmax = stp + 4.0 * (stp - stx)
    stp = max(stp, stpmin)
    stp = min(stp, stpmax)
    if (brackt and (stp <= stmin or stp >= stmax)) or (brackt and stmax - stmin <= XTOL * stmax):
        stp = stx
    state[_BRACKT] = 1.0 if brackt else 0.0
    state[_STX], state[_FX], state[_GX] = stx, fx, gx
    state[_STY], state[_FY], state[_GY] = sty, fy, gy
    state[_STMIN], state[_STMAX] = stmin, stmax
    return SEARCH_MORE, stp


@numba.njit(cache=True, nogil=True)
def direction(g, S, Y, rho, count, head, d, alpha):
    """d = −H g by the two-loop recursion over the `count` newest pairs, the newest at
    row `head` of S, Y (ring buffers of MEMORY rows), rho = 1 / sᵀy; H₀ = (sᵀy / yᵀy) I
    of the newest pair, the identity without one."""
    n = g.shape[0]
    m = S.shape[0]
    for c in range(n):
        d[c] = -g[c]
    k = head
    for _ in range(count):  # newest first
        a = 0.0
        for c in range(n):
            a += S[k, c] * d[c]
        a *= rho[k]
        alpha[k] = a
        for c in range(n):
            d[c] -= a * Y[k, c]
        k = (k - 1) % m
    if count > 0:
        yy = 0.0
        for c in range(n):
            yy += Y[head, c] * Y[head, c]
        gamma = 1.0 / (rho[head] * yy)
        for c in range(n):
            d[c] *= gamma
    k = (head - count + 1) % m
    for _ in range(count):  # oldest first
        b = 0.0
        for c in range(n):
            b += Y[k, c] * d[c]
        b *= rho[k]
        for c in range(n):
            d[c] += (alpha[k] - b) * S[k, c]
        k = (k + 1) % m


def workspace(n: int) -> tuple[np.ndarray, ...]:
    """S, Y (MEMORY, n), rho, alpha (MEMORY,), state (STATE_SIZE,) for a run over n
    variables."""
    return (np.zeros((MEMORY, n)), np.zeros((MEMORY, n)), np.zeros(MEMORY), np.zeros(MEMORY), np.zeros(STATE_SIZE))
