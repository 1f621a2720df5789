"""Plain-NumPy reference of the AFT anchor-bank evaluation (dense forward mode).

Used by the tests as an independent implementation of
:func:`jointsim.contact._aft_kernels.anchor_aft` + the diagonal products, and
by ``benchmarks/aft_throughput.py`` as the NumPy baseline.  Vectorised over
elements and sliders; a Python loop over samples; the derivative of every
anchor with respect to all 2 n_c coefficients (U, G) is carried densely.
"""
import numpy as np


def anchor_aft_numpy(U, G, gap0, kn, k, g, N0, basis, coupled, unilateral=True,
                     min_periods=2, max_periods=50, tol=1e-10, closing="sample"):
    """Forces and Jacobian blocks of anchored slider banks.

    Parameters
    ----------
    U, G : ndarray, shape (n_c, n_e)
        Slip and gap-change coefficients.
    gap0, kn, N0 : ndarray, shape (n_e,)
    k, g : ndarray, shape (n_e, n_s)
    basis : jointsim.harmonics.HarmonicBasis
    coupled : bool
    closing : str
        "interpolated": a slider separated at the sample before a closed one
        takes its anchor at the closing instant, where the linear interpolation
        of the gap between the two samples is 0; "sample": at the open sample.

    Returns
    -------
    Ft, Nc : ndarray, shape (n_e, n_c)
    Juu, Jug, JNN : ndarray, shape (n_e, n_c, n_c)
    """
    Gam, P = basis.Gam, basis.P
    nt, nc = Gam.shape
    ne, ns = k.shape
    u = (Gam @ U).T
    if coupled:
        gs = gap0[:, None] + (Gam @ G).T
        if unilateral:
            N = np.where(gs < 0.0, -kn[:, None] * gs, 0.0)
            dNdg = np.where(gs < 0.0, -kn[:, None], 0.0)
        else:
            N, dNdg = -kn[:, None] * gs, -kn[:, None] * np.ones_like(gs)
    else:
        N = np.broadcast_to(N0[:, None], (ne, nt)).copy()
        dNdg = np.zeros((ne, nt))
    w = np.zeros((ne, ns))
    dw = np.zeros((ne, ns, 2 * nc))          # d w / d(U, G)
    f = np.zeros((ne, nt))
    df = np.zeros((ne, nt, 2 * nc))
    du = np.concatenate([Gam, np.zeros_like(Gam)], axis=1)   # d u_t / d(U, G)
    dgv = np.concatenate([np.zeros_like(Gam), Gam], axis=1)  # d g_t / d(U, G)
    dF = np.zeros((ne, nc, 1 + 2 * nc))      # opening quadrature: value, d/d(U, G)
    for p in range(max_periods):
        w_start = w.copy()
        dF[:] = 0.0
        for t in range(nt):
            ut = u[:, t:t + 1]
            Nt = N[:, t:t + 1]
            if coupled and closing == "interpolated":
                tp = (t - 1) % nt
                cl = (N[:, t] > 0.0) & (N[:, tp] <= 0.0) & (gs[:, tp] > gs[:, t])
                if cl.any():
                    g0, g1 = gs[cl, tp], gs[cl, t]
                    th = g0 / (g0 - g1)
                    dth = (g1[:, None] * dgv[tp][None, :] - g0[:, None] * dgv[t][None, :]) \
                        * (-1.0 / (g0 - g1) ** 2)[:, None]
                    ud = u[cl, t] - u[cl, tp]
                    wc = u[cl, tp] + th * ud
                    dwc = (1 - th)[:, None] * du[tp][None, :] + th[:, None] * du[t][None, :] \
                        + ud[:, None] * dth
                    w[cl] = wc[:, None]
                    dw[cl] = dwc[:, None, :]
            dN = dNdg[:, t, None, None] * dgv[t][None, None, :]   # (ne, 1, 2nc)
            fs = g * Nt
            ft = k * (ut - w)
            sep = Nt <= 0.0
            slip_p = (~sep) & (ft > fs)
            slip_m = (~sep) & (ft < -fs)
            stick = ~(sep | slip_p | slip_m)
            fi = np.where(sep, 0.0, np.where(slip_p, fs, np.where(slip_m, -fs, ft)))
            sgn = np.where(slip_p, 1.0, np.where(slip_m, -1.0, 0.0))
            dfi = np.where(stick[..., None], k[..., None] * (du[t][None, None, :] - dw), 0.0) \
                + (sgn * g)[..., None] * dN
            w_new = np.where(sep, ut, np.where(slip_p | slip_m, ut - fi / k, w))
            dw = np.where(stick[..., None], dw,
                          du[t][None, None, :] - np.where(sep, 0.0, sgn * g / k)[..., None] * dN)
            w = w_new
            f[:, t] = fi.sum(axis=1)
            df[:, t] = dfi.sum(axis=1)
            if coupled and closing == "interpolated":
                _opening_quadrature(t, u, gs, N, dNdg, w, dw, k, g, du, dgv, Gam, P, dF)
        scale = np.abs(u).max(axis=1) + np.abs(w).max(axis=1)
        change = np.abs(w - w_start).max(axis=1) / np.where(scale > 0, scale, 1.0)
        if p + 1 >= min_periods and np.all(change <= tol):
            break
    Ft = f @ P.T + dF[:, :, 0]
    Nc = N @ P.T
    J = np.einsum("kt,etj->ekj", P, df) + dF[:, :, 1:]
    JNN = np.einsum("kt,et,tj->ekj", P, dNdg, Gam)
    return Ft, Nc, J[:, :, :nc], J[:, :, nc:], JNN


def _opening_quadrature(t, u, gs, N, dNdg, w, dw, k, g, du, dgv, Gam, P, dF):
    """Elements that are closed at sample ``t`` and open at the next: replace the
    trapezoid's ``P_t f_t / 2`` of that interval by the integral of the force up to
    the opening instant (gap linear, zero at ``phi``) against the linear weights
    ``P_t (2 - 3 s) + P_tn (3 s - 1)``, by 3-point Gauss-Legendre on the stuck and the
    slipping part (the force is linear on each), derivatives in forward mode at the
    nodes.  Writes ``dF[e, :, 0]`` (value) and ``dF[e, :, 1:]`` (by U, G)."""
    nt = u.shape[1]
    tn = (t + 1) % nt
    xg, wg = np.polynomial.legendre.leggauss(3)
    for e in np.flatnonzero((N[:, t] > 0) & (N[:, tn] <= 0) & (gs[:, tn] > gs[:, t])):
        g0, g1 = gs[e, t], gs[e, tn]
        phi = g0 / (g0 - g1)
        dphi = (g0 * dgv[tn] - g1 * dgv[t]) / (g0 - g1) ** 2
        for i in range(k.shape[1]):
            F0 = k[e, i] * (u[e, t] - w[e, i])
            Dl = k[e, i] * (u[e, tn] - u[e, t])
            S = g[e, i] * N[e, t]
            tr = F0 + phi * Dl
            sg = np.sign(tr)
            s1 = phi if sg == 0 else np.clip((sg * S - F0) / (Dl + sg * S / phi), 0.0, phi)
            dF0 = k[e, i] * (du[t] - dw[e, i])
            dD = k[e, i] * (du[tn] - du[t])
            dS = g[e, i] * dNdg[e, t] * dgv[t]
            tot = np.zeros((P.shape[0], 1 + dF.shape[2] - 1))
            for lo, hi, stuck in ((0.0, s1, True), (s1, phi, False)):
                for x, wt in zip(xg, wg):
                    sq = lo + (hi - lo) * (x + 1) / 2
                    h = wt * (hi - lo) / 2
                    if stuck:
                        fv = F0 + sq * Dl
                        dfv = dF0 + sq * dD
                    else:
                        fv = sg * S * (1 - sq / phi)
                        dfv = sg * (dS * (1 - sq / phi) + S * sq / phi ** 2 * dphi)
                    wv = P[:, t] * (2 - 3 * sq) + P[:, tn] * (3 * sq - 1)
                    tot[:, 0] += h * fv * wv
                    tot[:, 1:] += h * wv[:, None] * dfv[None, :]
            tot[:, 0] -= P[:, t] * F0 / 2
            tot[:, 1:] -= P[:, t][:, None] * dF0[None, :] / 2
            dF[e] += tot


def aft_history_fd(aft, U, G, columns, h=1e-7):
    """Central differences of an AFT's contact-force coefficients by single
    coefficient rows of ``U`` and of ``G`` (every element at once: the elements
    are independent).

    Parameters
    ----------
    aft : jointsim.solvers.aft.AFT
    U, G : ndarray, shape (n_c, n_e)
        Slip and gap-change coefficients of the point.
    columns : iterable of int
        Coefficient rows to perturb.
    h : float
        Step.

    Yields
    ------
    which : str
        ``"u"`` (compare with ``Juu``) or ``"g"`` (with ``Jug``).
    j : int
        The perturbed row.
    fd : ndarray, shape (n_e, n_c)
        ``d Ft / d X[j, :]``, element by element.
    """
    for j in columns:
        for which in ("u", "g"):
            X = U if which == "u" else G
            dX = np.zeros_like(X)
            dX[j] = h

            def Ft(sign):
                Xs = X + sign * dX
                args = (Xs, G) if which == "u" else (U, Xs)
                return aft.evaluate(*args, jacobian=False).Ft

            yield which, j, (Ft(1) - Ft(-1)) / (2 * h)
