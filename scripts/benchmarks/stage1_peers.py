"""Stage-1 peers of the Pitot sweep written as a competent user would (NumPy and JAX).

Tr[R] of the unconstrained xi1 at each candidate of ``models/pitot5hole.py``, from the
per-sample arrays of :func:`bench.pitot_sweep_inputs`: the model's algebra reduced by hand to
two BLAS products per channel and chunk of candidates (every Gram entry is a sum of
u_j {1, s, w_j, s w_j} or u_j^2 {1, s, s^2}), batched 5x5 normal equations (column-scaled).
``NumpySweep`` runs it in NumPy (threads over chunks); ``jax_batched_factory`` is the same
algebra under ``jax.jit`` (CPU, float64). From the project's shared peer set; used by
``scripts/benchmarks/bench.py --parts stage1``.
"""

from __future__ import annotations

import numpy as np


def peer_inputs(inp: dict) -> dict:
    """The bench's sweep inputs under the peers' names (s: airspeed, L: lever-arm velocity)."""
    return {"pa": inp["pa"], "pb": inp["pb"], "s": inp["speed"], "C": inp["C"], "L": inp["lever"], "z": inp["z"],
            "deg": inp["deg"]}


class NumpySweep:
    """Tr[R] per candidate, vectorised NumPy, batched normal equations.

    Algebra: v_NED = (1 + lambda_V) s u + b_V u - L + W with u = C_b^n C(eps) d(alpha, beta),
    so for channel j the columns of A are [s u_j, u_j, e_j] and y_j = w_j - s u_j, w = z + L.
    Every Gram entry is one of sum_k u_j {1, s, w_j, s w_j} and sum_k u_j^2 {1, s, s^2}: two
    BLAS matrix products per channel on a chunk of candidates (K_c, N) @ (N, 4) and (N, 3).
    The trig and the rotation are elementwise NumPy on (K_c, N) arrays.
    """

    def __init__(self, inp, chunk: int = 16):
        self.pa, self.pb, self.s = inp["pa"], inp["pb"], inp["s"]
        self.C = np.ascontiguousarray(inp["C"].transpose(1, 2, 0))  # (3, 3, N)
        self.deg = inp["deg"]
        N = self.N = len(self.s)
        w = inp["z"] + inp["L"]
        one = np.ones(N)
        self.Dlin = [np.ascontiguousarray(np.column_stack([one, self.s, w[:, j], self.s * w[:, j]])) for j in range(3)]
        self.Dq = np.ascontiguousarray(np.column_stack([one, self.s, self.s ** 2]))
        self.sumw = w.sum(0)
        self.sumw2 = (w * w).sum(0)
        self.chunk = chunk

    def _chunk(self, c):
        Kc, N, deg = len(c), self.N, self.deg
        la, ba, lb, bb, eps = (c[:, k][:, None] for k in range(5))
        alpha = ((1 + la) * deg) * self.pa + ba * deg
        beta = ((1 + lb) * deg) * self.pb + bb * deg
        ca_, sa, cb, sb = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
        d1 = ca_ * cb
        d3 = sa * cb
        ce, se = np.cos(eps), np.sin(eps)
        e2 = ce * sb + se * d3          # (C_eps d)_2
        e3 = ce * d3 - se * sb          # (C_eps d)_3
        G = np.zeros((Kc, 3, 6, 6))
        for j in range(3):
            Cj = self.C[j]
            u = Cj[0] * d1 + Cj[1] * e2 + Cj[2] * e3                     # (Kc, N)
            S1 = u @ self.Dlin[j]                                          # sum u, su, uw, suw
            S2 = (u * u) @ self.Dq                                         # sum u2, su2, s2u2
            Su, Ssu, Suw, Ssuw = S1.T
            Su2, Ssu2, Ss2u2 = S2.T
            g = G[:, j]
            g[:, 0, 0] = Ss2u2
            g[:, 0, 1] = g[:, 1, 0] = Ssu2
            g[:, 1, 1] = Su2
            g[:, 0, 2 + j] = g[:, 2 + j, 0] = Ssu
            g[:, 1, 2 + j] = g[:, 2 + j, 1] = Su
            g[:, 2 + j, 2 + j] = N
            g[:, 0, 5] = g[:, 5, 0] = Ssuw - Ss2u2
            g[:, 1, 5] = g[:, 5, 1] = Suw - Ssu2
            g[:, 2 + j, 5] = g[:, 5, 2 + j] = self.sumw[j] - Ssu
            g[:, 5, 5] = self.sumw2[j] - 2 * Ssuw + Ss2u2
        return G

    def gram(self, cands, threads: int = 1):
        parts = [cands[i:i + self.chunk] for i in range(0, len(cands), self.chunk)]
        if threads == 1:
            return np.concatenate([self._chunk(p) for p in parts])
        from concurrent.futures import ThreadPoolExecutor
        with ThreadPoolExecutor(threads) as pool:
            return np.concatenate(list(pool.map(self._chunk, parts)))

    def trace(self, cands, threads: int = 1):
        return solve_gram(self.gram(cands, threads), self.N)[1]


def solve_gram(G, N):
    """xi1 and Tr[R] from per-channel Gram matrices (K, 3, n1+1, n1+1): column-scaled normal equations."""
    n1 = G.shape[-1] - 1
    AtA, Aty, yty = G[:, :, :n1, :n1], G[:, :, :n1, n1], G[:, :, n1, n1]
    P, q = AtA.sum(1), Aty.sum(1)
    d = np.sqrt(np.diagonal(P, axis1=1, axis2=2))
    x = np.linalg.solve(P / (d[:, :, None] * d[:, None, :]), (q / d)[..., None])[..., 0] / d
    rss = yty - 2 * np.einsum("mjn,mn->mj", Aty, x) + np.einsum("mn,mjnk,mk->mj", x, AtA, x)
    return x, (rss / N).sum(1)



def jax_batched_factory(inp, chunk: int = 50):
    """JAX, second formulation (the faster one in jax_variants.py): explicit (K_c, N) arrays per chunk of
    candidates and matmul reductions, i.e. NumPy's algebra under jax.jit (CPU, float64)."""
    import jax
    import jax.numpy as jnp
    jax.config.update("jax_enable_x64", True)
    pa, pb = jnp.asarray(inp["pa"]), jnp.asarray(inp["pb"])
    C = jnp.asarray(np.ascontiguousarray(inp["C"].transpose(1, 2, 0)))
    w = np.ascontiguousarray((inp["z"] + inp["L"]).T)
    s, deg, N = inp["s"], inp["deg"], len(inp["s"])
    one = np.ones(N)
    Dlin = jnp.asarray(np.stack([np.column_stack([one, s, w[j], s * w[j]]) for j in range(3)]))
    Dq = jnp.asarray(np.column_stack([one, s, s ** 2]))
    sumw, sumw2 = jnp.asarray(w.sum(1)), jnp.asarray((w * w).sum(1))

    @jax.jit
    def trace(c):
        la, ba, lb, bb, eps = (c[:, k][:, None] for k in range(5))
        al = ((1 + la) * deg) * pa + ba * deg
        be = ((1 + lb) * deg) * pb + bb * deg
        ca_, sa, cb, sb = jnp.cos(al), jnp.sin(al), jnp.cos(be), jnp.sin(be)
        d1, d3 = ca_ * cb, sa * cb
        ce, se = jnp.cos(eps), jnp.sin(eps)
        e2, e3 = ce * sb + se * d3, ce * d3 - se * sb
        S1, S2 = [], []
        for j in range(3):
            u = C[j, 0] * d1 + C[j, 1] * e2 + C[j, 2] * e3
            S1.append(u @ Dlin[j])
            S2.append((u * u) @ Dq)
        S1, S2 = jnp.stack(S1, 1), jnp.stack(S2, 1)
        Su, Ssu, Suw, Ssuw = (S1[..., i] for i in range(4))
        Su2, Ssu2, Ss2u2 = (S2[..., i] for i in range(3))
        Kc = c.shape[0]
        G = jnp.zeros((Kc, 3, 6, 6))
        j = jnp.arange(3)
        G = G.at[:, :, 0, 0].set(Ss2u2).at[:, :, 0, 1].set(Ssu2).at[:, :, 1, 0].set(Ssu2).at[:, :, 1, 1].set(Su2)
        G = G.at[:, j, 0, 2 + j].set(Ssu).at[:, j, 2 + j, 0].set(Ssu).at[:, j, 1, 2 + j].set(Su).at[:, j, 2 + j, 1].set(Su)
        G = G.at[:, j, 2 + j, 2 + j].set(float(N))
        G = G.at[:, :, 0, 5].set(Ssuw - Ss2u2).at[:, :, 5, 0].set(Ssuw - Ss2u2)
        G = G.at[:, :, 1, 5].set(Suw - Ssu2).at[:, :, 5, 1].set(Suw - Ssu2)
        G = G.at[:, j, 2 + j, 5].set(sumw - Ssu).at[:, j, 5, 2 + j].set(sumw - Ssu)
        G = G.at[:, :, 5, 5].set(sumw2 - 2 * Ssuw + Ss2u2)
        AtA, Aty, yty = G[..., :5, :5], G[..., :5, 5], G[..., 5, 5]
        P, q = AtA.sum(1), Aty.sum(1)
        dd = jnp.sqrt(jnp.diagonal(P, axis1=1, axis2=2))
        x = jnp.linalg.solve(P / (dd[:, :, None] * dd[:, None, :]), (q / dd)[..., None])[..., 0] / dd
        rss = yty - 2 * jnp.einsum("mjn,mn->mj", Aty, x) + jnp.einsum("mn,mjnk,mk->mj", x, AtA, x)
        return rss.sum(1) / N

    def run(cands):
        return np.concatenate([np.asarray(trace(jnp.asarray(cands[i:i + chunk]))) for i in range(0, len(cands), chunk)])

    return run
