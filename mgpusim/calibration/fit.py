"""Least-squares fits with uncertainties, residuals and a conditioning check.

Costs must stay physical (no negative ns per pixel), so the fit is non-negative least squares
on relative errors (each row weighted by 1 / measured duration, since durations span orders
of magnitude). Standard errors come from the linearised covariance at the solution.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mgpusim.model.errors import InputError

#: Above this condition number (of the column-scaled design matrix) a fit is reported as
#: ill-conditioned: its coefficients trade off against each other and mean little alone.
ILL_CONDITIONED = 1e4


@dataclass
class Fit:
    names: list[str]
    coef: np.ndarray
    stderr: np.ndarray
    rel_residuals: np.ndarray
    condition: float
    warnings: list[str] = field(default_factory=list)

    @property
    def rel_rms(self) -> float:
        return float(np.sqrt(np.mean(self.rel_residuals ** 2))) if len(self.rel_residuals) else 0.0

    def as_dict(self) -> dict[str, dict[str, float]]:
        return {n: {"value": float(c), "stderr": float(s)} for n, c, s in zip(self.names, self.coef, self.stderr)}


def fit_nonnegative(X: np.ndarray, y: np.ndarray, names: list[str], what: str) -> Fit:
    """Fit y ~ X @ coef, coef >= 0, minimising relative error."""
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    warnings: list[str] = []
    if len(y) == 0:
        raise InputError(f"{what}: no measurements")
    if not (np.isfinite(X).all() and np.isfinite(y).all()) or (y <= 0).any():
        # the solver must never see these (NaN crashes scipy's nnls natively)
        raise InputError(f"{what}: durations and work terms must be finite and durations > 0")
    w = 1.0 / np.maximum(y, 1.0)
    Xw = X * w[:, None]
    scale = np.linalg.norm(Xw, axis=0)
    used = scale > 0
    for name in map(str, np.array(names)[~used]):
        warnings.append(f"{what}: no measurement varies {name!r}; it is fixed at 0")
    Xs = Xw[:, used] / scale[used]
    condition = float(np.linalg.cond(Xs)) if Xs.size else float("inf")
    rank = np.linalg.matrix_rank(Xs) if Xs.size else 0
    if rank < Xs.shape[1]:
        warnings.append(f"{what}: the measurements cannot tell {[n for n, u in zip(names, used) if u]} apart "
                        f"(rank {rank} < {Xs.shape[1]}): sweep more sizes")
    elif condition > ILL_CONDITIONED:
        warnings.append(f"{what}: ill-conditioned fit (condition number {condition:.3g}); "
                        "coefficients are uncertain, see their stderr")
    from scipy.optimize import nnls  # noqa: PLC0415 - here, so measuring never needs scipy

    maxiter = 50 * max(1, Xs.shape[1])
    try:
        sol, _ = nnls(Xs, np.ones_like(y), maxiter=maxiter)
    except RuntimeError:  # scipy: "Maximum number of iterations reached"
        raise InputError(f"{what}: the non-negative least-squares fit did not converge in {maxiter} "
                         "iterations; the measurements cannot be fitted (sweep more distinct sizes)"
                         ) from None
    coef = np.zeros(len(names))
    coef[used] = sol / scale[used]
    pred = X @ coef
    rel = (pred - y) / y
    stderr = _stderr(Xs, rel, scale[used], used, len(names))
    return Fit(list(names), coef, stderr, rel, condition, warnings)


def _stderr(Xs: np.ndarray, rel: np.ndarray, scale: np.ndarray, used: np.ndarray, n: int) -> np.ndarray:
    out = np.full(n, np.nan)
    dof = len(rel) - Xs.shape[1]
    if dof <= 0:
        return out
    s2 = float(rel @ rel) / dof
    try:
        cov = s2 * np.linalg.pinv(Xs.T @ Xs)
    except np.linalg.LinAlgError:
        return out
    out[used] = np.sqrt(np.clip(np.diag(cov), 0, None)) / scale
    return out
