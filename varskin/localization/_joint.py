"""One joint Gauss-Newton step over every sensor's peak and every touch's nuisances.

Why it exists: the batch solve alternates between the sensors' fits (touches held fixed)
and the touches' gain and placement (sensors held fixed). That block coordinate descent
crawls along the valley in which a touch's placement offset and the positions of the
sensors it lights move together: after 4 alternations a finger session's estimates were
still 0.2-0.3 mm (median) from where 40 alternations take them, and the live view could
never match a batch that had not settled. A joint step linearizes both at once and solves
the coupled normal equations exactly: each touch's 3 nuisances (log gain, x and y offset)
are a 3x3 block that is eliminated first, which leaves a sparse system over the sensors'
parameters (sensors couple only through the touches they share).

The cost is the sum of the per-sensor robust costs of ``_peak_model.fit`` (each divided by
that sensor's residual variance, so sensors weigh by their own noise) and the touches'
Gaussian priors, so the step improves the same objective both halves of the alternation
improve. Windows and residual scales are held at their values at the start of the step.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from varskin.localization import _peak_model as pm
from varskin.localization._maps import packed

if TYPE_CHECKING:
    from varskin.localization.peakfit import Localizer

NP = pm.N_PARAMS
DENSE_UP_TO = 600  # unknowns; a bigger reduced system is solved by conjugate gradients
CG_MAX_ITER = 500  # ... and factorized if they have not converged by then


def joint_step(loc: Localizer, damping: float = 1e-3) -> bool:
    """Move every located sensor and every touch by one damped joint Gauss-Newton step.

    Returns False when there is nothing to do or the step did not lower the cost.
    """
    f = loc.fit
    K = loc._k
    s = loc.settings
    cols = np.flatnonzero(f.has_model())
    S = cols.size
    if S == 0 or K < 3:
        return False
    h = loc.spacing()
    min_radius = s.window_spacings * h
    theta = f.theta[cols].copy()
    lg = loc._lg[:K].copy()
    d = loc._dxy[:K].copy()
    P0 = loc._P[:K]

    # The touches inside each sensor's window, gathered into (M, S) as the fit does.
    Pe = P0 + d
    w = pm.half_width(theta)
    reach = 1.5 * np.maximum(s.window_widths * w, min_radius)
    dist = np.hypot(Pe[:, 0:1] - theta[:, pm.SX], Pe[:, 1:2] - theta[:, pm.SY])
    V = loc._V[:K][:, cols] * loc._sign
    valid = np.isfinite(V) & ~loc._clipped(cols) & ~loc._missed[:K, None]
    inside = (dist <= reach[None, :]) & valid
    order, sel = packed(inside)  # (M, S) touch indices
    at = (order, np.arange(S))
    tau = (loc._tau()[:, None] - f.tc[cols][None, :])[at]
    U = (V[at] - f.floor[cols]) / f.amp[cols]
    U = np.where(sel, U, 0.0)
    sc = np.maximum(f.scale[cols], 1e-9)
    rho = loc._ridge_width(theta)
    width_mean = None if loc.shared_lw is None else np.tile(loc.shared_lw, (S, 1))
    Q, mu = pm.sensor_priors(S, s, width_mean, 0.5 * (theta[:, pm.LW] + theta[:, pm.LWY]))
    prior_t = np.array([1.0 / loc.gain_sd**2] + [1.0 / loc.place_sd_mm**2] * 2)
    # The window stays where the step starts: moving away from the data must not pay.
    win = pm.window(Pe[order], theta, min_radius, s) * sel
    c2 = s.cauchy_c**2

    def cost(th: np.ndarray, lg_: np.ndarray, d_: np.ndarray) -> float:
        r = U - pm.model((P0 + d_)[order], tau, th, np.exp(lg_)[order], rho, s.shape)
        data = c2 * float((win * np.log1p((r / (s.cauchy_c * sc)) ** 2)).sum())
        z = np.column_stack([lg_, d_])
        return data + float(pm.prior_cost_of(th, Q, mu, s).sum()) + float((z * z * prior_t).sum())

    m, J = pm.jacobian(Pe[order], tau, theta, np.exp(lg)[order], rho, s.shape)
    r = U - m
    z = r / (s.cauchy_c * sc)
    wgt = win / (1.0 + z * z) / (sc * sc)  # IRLS weights of the Cauchy loss, per sensor
    # A touch's reading moves with its gain as the bump does, and with its placement as
    # the sensor's position does, with the opposite sign.
    Jt = np.stack([m - pm.floor(tau, theta), -J[..., pm.SX], -J[..., pm.SY]], axis=-1)

    Qi = pm.prior_hessian_of(theta, Q, s)
    Hss = np.einsum("ms,msp,msq->spq", wgt, J, J) + Qi
    gs = np.einsum("ms,msp,ms->sp", wgt, J, r) - np.einsum("spq,sq->sp", Qi, theta - mu)
    me, se = np.nonzero(sel)  # one entry per (touch in window, sensor)
    ke = order[me, se]
    we = wgt[me, se]
    B = np.einsum("e,ep,eq->epq", we, J[me, se], Jt[me, se])  # (E, NP, 3): d2/dsensor dtouch
    Htt = np.zeros((K, 3, 3))
    gt = np.zeros((K, 3))
    np.add.at(Htt, ke, np.einsum("e,ep,eq->epq", we, Jt[me, se], Jt[me, se]))
    np.add.at(gt, ke, (we * r[me, se])[:, None] * Jt[me, se])
    Htt += np.diag(prior_t)[None]
    gt -= prior_t[None, :] * np.column_stack([lg, d])
    # Levenberg-Marquardt damping on both blocks (relative, with a floor for empty rows).
    Hss += np.eye(NP)[None] * (damping * np.diagonal(Hss, axis1=1, axis2=2)[:, None, :] + 1e-9)
    Htt += np.eye(3)[None] * (damping * np.diagonal(Htt, axis1=1, axis2=2)[:, None, :])
    # Eliminate the touches: A = Hss - B^T Htt^-1 B, with B (3K x S*NP) the sensor-touch
    # cross terms; a sensor couples only to the sensors it shares touches with.
    n = S * NP
    iT = np.linalg.inv(Htt)
    Bs = cross_terms(B, ke, se, K, S)
    rhs = gs.ravel() - Bs.T @ (iT @ gt[:, :, None]).ravel()
    try:
        if n <= DENSE_UP_TO:
            Bd = Bs.toarray()
            A = -(Bd.T @ (iT @ Bd.reshape(K, 3, n)).reshape(3 * K, n))
            idx = np.arange(S)[:, None, None] * NP
            A[idx + np.arange(NP)[None, :, None], idx + np.arange(NP)[None, None, :]] += Hss
            ds = scipy.linalg.solve(A, rhs, assume_a="sym")
        else:
            ds = _solve_reduced(Hss, Bs, iT, rhs, _own_blocks(Hss, B, ke, se, iT))
    except (np.linalg.LinAlgError, RuntimeError, ValueError):
        return False
    if not np.isfinite(ds).all():
        return False
    dt = (iT @ (gt - (Bs @ ds).reshape(K, 3))[:, :, None])[:, :, 0]
    ds = ds.reshape(S, NP)

    # The same step limits as the fit and the touch estimate use.
    ds[:, [pm.LW, pm.LWY]] = np.clip(ds[:, [pm.LW, pm.LWY]], -0.5, 0.5)
    ds[:, [pm.SX, pm.SY]] = np.clip(ds[:, [pm.SX, pm.SY]], -0.5 * min_radius, 0.5 * min_radius)
    lim = pm.offset_limit(loc.place_sd_mm)
    dt[:, 0] = np.clip(dt[:, 0], -1.0, 1.0)
    dt[:, 1:] = np.clip(dt[:, 1:], -lim, lim)
    lo, hi = np.log(pm.MIN_WIDTH_SPACINGS * h), np.log(pm.MAX_WIDTH_SPACINGS * h)
    c0 = cost(theta, lg, d)
    for t in (1.0, 0.5, 0.25):
        th1 = theta + t * ds
        th1[:, pm.AMP] = np.maximum(th1[:, pm.AMP], 1e-6)
        th1[:, [pm.LW, pm.LWY]] = np.clip(th1[:, [pm.LW, pm.LWY]], lo, hi)
        lg1 = np.clip(lg + t * dt[:, 0], *pm.LOG_GAIN_RANGE)
        d1 = np.clip(d + t * dt[:, 1:], -lim, lim)
        c1 = cost(th1, lg1, d1)
        if np.isfinite(c1) and c1 <= c0:
            f.theta[cols] = th1
            loc._lg[:K] = lg1
            loc._dxy[:K] = d1
            return True
    return False


def cross_terms(
    B: np.ndarray, ke: np.ndarray, se: np.ndarray, K: int, S: int
) -> scipy.sparse.csr_matrix:
    """(3K, S*NP) sparse sensor-touch cross terms from their (E, NP, 3) blocks ``B``; block
    e joins touch ``ke[e]`` and sensor ``se[e]`` (each pair at most once)."""
    return scipy.sparse.csr_matrix(
        (
            B.transpose(0, 2, 1).ravel(),
            (
                np.repeat(ke[:, None] * 3 + np.arange(3)[None, :], NP, axis=1).ravel(),
                np.tile(se[:, None] * NP + np.arange(NP)[None, :], (1, 3)).ravel(),
            ),
        ),
        shape=(3 * K, S * NP),
    )


def _own_blocks(
    Hss: np.ndarray, B: np.ndarray, ke: np.ndarray, se: np.ndarray, iT: np.ndarray
) -> np.ndarray:
    """(S, NP, NP) each sensor's own block of the reduced matrix: its Hessian less what the
    touches it sees take, B_e Htt^-1 B_e^T over its touch-sensor pairs e (``B`` (E, NP, 3),
    pair e joins touch ``ke[e]`` and sensor ``se[e]``)."""
    own = Hss.copy()
    np.add.at(own, se, -np.einsum("epa,eab,eqb->epq", B, iT[ke], B, optimize=True))
    return own


def _solve_reduced(
    Hss: np.ndarray, Bs, iT: np.ndarray, rhs: np.ndarray, own: np.ndarray
) -> np.ndarray:
    """Solve (Hss - B^T Htt^-1 B) x = rhs for a board-sized system without forming it.

    The reduced matrix is symmetric positive definite (a Schur complement of the damped
    joint Hessian), and each sensor's own block ``own`` (S, NP, NP) dominates it, so
    conjugate gradients preconditioned by those blocks converge in a few dozen products,
    each two sparse matrix-vector products. Forming the matrix and factorizing it
    (SuperLU) cost several times more on the full board; that stays as the fallback.
    """
    S = Hss.shape[0]
    K = iT.shape[0]
    n = S * NP

    def matvec(v: np.ndarray) -> np.ndarray:
        t = (iT @ (Bs @ v).reshape(K, 3, 1)).ravel()
        return (Hss @ v.reshape(S, NP, 1)).ravel() - Bs.T @ t

    pinv = np.linalg.inv(own)

    def precond(v: np.ndarray) -> np.ndarray:
        return (pinv @ v.reshape(S, NP, 1)).ravel()

    op = scipy.sparse.linalg.LinearOperator((n, n), matvec=matvec, dtype=float)
    M = scipy.sparse.linalg.LinearOperator((n, n), matvec=precond, dtype=float)
    x, info = scipy.sparse.linalg.cg(op, rhs, M=M, rtol=1e-10, maxiter=CG_MAX_ITER)
    if info == 0:
        return x
    A = _block_diagonal(Hss) - Bs.T @ _block_diagonal(iT) @ Bs
    return scipy.sparse.linalg.splu(A.tocsc()).solve(rhs)


def _block_diagonal(blocks: np.ndarray) -> scipy.sparse.csr_matrix:
    """A sparse block-diagonal matrix from (N, b, b) blocks."""
    N, b, _ = blocks.shape
    base = np.arange(N)[:, None, None] * b
    rows = np.broadcast_to(base + np.arange(b)[None, :, None], blocks.shape)
    cols = np.broadcast_to(base + np.arange(b)[None, None, :], blocks.shape)
    return scipy.sparse.csr_matrix(
        (blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(N * b, N * b)
    )
