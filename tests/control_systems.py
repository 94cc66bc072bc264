"""Random test systems for the control toolbox: generic, marginally stable (eigenvalues on the imaginary axis or
the unit circle) and badly scaled (a diagonal similarity with factors 10^-2..10^2, so entries span ~1e-4..1e4)."""

import numpy as np

KINDS = ("generic", "marginal", "scaled")


def _marginal_A(rng, n, discrete):
    """A real A with a pair of eigenvalues on the stability boundary (and a real one on it when n is odd)."""
    blocks = []
    k = n
    w = rng.uniform(0.5, 2.0)
    if discrete:
        c, s = np.cos(w), np.sin(w)
        blocks.append(np.array([[c, -s], [s, c]]))
    else:
        blocks.append(np.array([[0.0, -w], [w, 0.0]]))
    k -= 2
    if k % 2:
        blocks.append(np.array([[1.0 if discrete else 0.0]]))
        k -= 1
    while k > 0:  # the rest strictly stable
        r = rng.uniform(0.2, 0.8) if discrete else -rng.uniform(0.5, 2.0)
        blocks.append(np.array([[r]]))
        k -= 1
    J = np.zeros((n, n))
    i = 0
    for b in blocks:
        J[i:i + len(b), i:i + len(b)] = b
        i += len(b)
    V = rng.standard_normal((n, n)) + 2 * np.eye(n)
    return V @ J @ np.linalg.inv(V)


def system(seed, kind, n=4, m=2, p=2, discrete=False, stable=None):
    """(A, B, C, D) of the given kind. ``stable``: True shifts A to strict stability, False to instability."""
    rng = np.random.default_rng(seed)
    if kind == "marginal":
        A = _marginal_A(rng, n, discrete)
    else:
        A = rng.standard_normal((n, n)) / (np.sqrt(n) if discrete else 1.0)
        if stable is not None:
            lam = np.linalg.eigvals(A)
            if discrete:
                A = A * (rng.uniform(0.3, 0.9) if stable else rng.uniform(1.1, 1.5)) / np.abs(lam).max()
            else:
                A = A - (lam.real.max() + (rng.uniform(0.2, 1.0) if stable else -rng.uniform(0.2, 1.0))) * np.eye(n)
    B = rng.standard_normal((n, m))
    C = rng.standard_normal((p, n))
    D = rng.standard_normal((p, m))
    if kind == "scaled":
        T = 10.0 ** rng.uniform(-2, 2, n)
        A = (T[:, None] * A) / T[None, :]
        B = T[:, None] * B
        C = C / T[None, :]
    return A, B, C, D


def batch(count, n=4, m=2, p=2, discrete=False, stable=None, seed=0, kinds=KINDS):
    """``count`` systems cycling through ``kinds``: a list of (kind, A, B, C, D)."""
    return [(kinds[i % len(kinds)],) + system(seed + i, kinds[i % len(kinds)], n, m, p, discrete, stable)
            for i in range(count)]


def stack(systems):
    """The systems' matrices stacked for vmap: (A, B, C, D) with a leading batch axis."""
    return tuple(np.stack([s[i] for s in systems]) for i in range(1, 5))


def weights(seed, n, m):
    """(Q, R, N) from a random positive definite joint weight [[Q, N], [N^T, R]]."""
    rng = np.random.default_rng(10_000 + seed)
    M = rng.standard_normal((n + m, n + m))
    J = M @ M.T + 0.1 * np.eye(n + m)
    return J[:n, :n], J[n:, n:], J[:n, n:]


def rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return np.linalg.norm(a - b) / np.linalg.norm(b)


def fd_grad(f, x, h=1e-6):
    """Central finite differences of f (scalar- or array-valued) over the entries of x: shape x.shape + f's."""
    x = np.asarray(x, dtype=float)
    g = None
    for i in np.ndindex(x.shape):
        e = np.zeros_like(x)
        e[i] = h * max(1.0, abs(x[i]))
        d = (np.asarray(f(x + e)) - np.asarray(f(x - e))) / (2 * e[i])
        if g is None:
            g = np.zeros(x.shape + d.shape)
        g[i] = d
    return g


def eig_match(E1, E2):
    """Largest distance from an eigenvalue of one set to the nearest of the other, relative to the spectrum size."""
    E1, E2 = np.asarray(E1), np.asarray(E2)
    d = np.abs(E1[:, None] - E2[None, :])
    return max(d.min(axis=1).max(), d.min(axis=0).max()) / max(1.0, np.abs(E2).max())
