"""Every closure evaluated once per test session, on every state any closure test needs.

Compiling a closure is what costs time (the exact closure FEC takes tens of seconds
per jitted program), so the closure tests do not jit closures themselves: each
(closure, dimension) is compiled once, as *one* program, and evaluated once on one
batch that holds every test state, labelled by group (:data:`GROUPS`). The program is

    vmap over two members ( native batch f(x) and its VJP with a fixed cotangent W )

so every value the tests check has gone through jit, vmap and native batching at
once; the two vmap members hold the same states in opposite order (they must agree),
and the VJP gives, at every state, the gradient of the linear functional
``F(a2) = sum(f(a2) * W)``, which the tests compare with central differences of the
same F on the states ``x +- h e`` of the ``fd_*`` groups.
"""
from __future__ import annotations

import functools

import numpy as np
import scipy.linalg as sl

from pyfold._jax import jax, jnp
from pyfold import closures as C
from pyfold import tensors as T
from pyfold.closures import _natural_fit as NATURAL_FIT

#: Step of the central differences [dimensionless, a2 components].
FD_STEP = 1e-5
SHEAR = np.zeros((3, 3))
SHEAR[0, 1] = 1.0


def random_a2(d: int, n: int, seed: int, n_vectors: int = 400) -> np.ndarray:
    """Valid orientation tensors from isotropic to nearly aligned: moments of random
    anisotropic populations."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        g = rng.normal(size=(n_vectors, d)) * rng.uniform(0.05, 1.0, size=d)
        p = g / np.linalg.norm(g, axis=1, keepdims=True)
        out.append(p.T @ p / len(p))
    return np.stack(out)


def rotation(d: int) -> np.ndarray:
    if d == 2:
        th = 0.7
        return np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    return np.linalg.qr(np.random.default_rng(5).normal(size=(3, 3)))[0]


def directions(d: int) -> tuple[np.ndarray, np.ndarray]:
    """A generic direction and an axis (where the two zero eigenvalues repeat)."""
    return (np.array([0.6, 0.8, 0.0]) if d == 3 else np.array([0.6, 0.8]), np.eye(d)[0])


def rotate4(R: np.ndarray, a4: np.ndarray) -> np.ndarray:
    return np.einsum("ia,jb,kc,ld,...abcd->...ijkl", R, R, R, R, a4)


def sphere_rule(n_theta: int, n_phi: int):
    """Gauss-Legendre in cos(theta) x uniform phi: weights sum to one."""
    x, w = np.polynomial.legendre.leggauss(n_theta)
    phi = 2 * np.pi * np.arange(n_phi) / n_phi
    ct, ph = np.meshgrid(x, phi, indexing="ij")
    st = np.sqrt(1 - ct**2)
    p = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1).reshape(-1, 3)
    return p, np.repeat(w, n_phi) / (2 * n_phi)


def jeffery_population(L, lam, t, rule):
    """Directions ``p = B p0 / |B p0|``, ``B = exp(t (W + lam D))``, of an isotropic start,
    with their quadrature weights and ``B``."""
    D, W = 0.5 * (L + L.T), 0.5 * (L - L.T)
    B = sl.expm(t * (W + lam * D))
    p0, w = rule
    p = p0 @ B.T
    return p / np.linalg.norm(p, axis=1, keepdims=True), w, B


#: (velocity gradient, lambda, time) of the Jeffery populations from isotropy.
JEFFERY_CASES = (
    (SHEAR, 0.8, 4.0),  # shear, finite aspect ratio
    (np.diag([1.0, -0.5, -0.5]), 1.0, 0.8),  # uniaxial elongation: repeated eigenvalues
    (np.diag([1.0, -1.0, 0.0]) + 0.3 * SHEAR, 0.9, 0.7),  # mixed planar flow
)


@functools.cache
def jeffery_populations():
    """a2, a4 (population quadrature) and ``B B^T`` of each :data:`JEFFERY_CASES` entry."""
    rule = sphere_rule(96, 192)
    out = []
    for L, lam, t in JEFFERY_CASES:
        p, w, B = jeffery_population(L, lam, t, rule)
        out.append((np.asarray(T.a2_from_vectors(p, w)), np.asarray(T.a4_from_vectors(p, w)), B @ B.T))
    return out


def planar_shear_population():
    """2-D Jeffery population (lambda = 1, t = 2) from 256 equally spaced directions."""
    th = 2 * np.pi * (np.arange(256) + 0.5) / 256
    p0 = np.stack([np.cos(th), np.sin(th)], axis=1)
    B = sl.expm(2.0 * np.array([[0.0, 1.0], [0.0, 0.0]]))
    p = p0 @ B.T
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return np.asarray(T.a2_from_vectors(p)), np.asarray(T.a4_from_vectors(p))


def fd_directions(d: int) -> list[np.ndarray]:
    """Trace-free symmetric perturbations (stay on tr a2 = 1): off-diagonal ones probe
    the axes, which are arbitrary at isotropy."""
    pairs = [(0, 1), (1, 2), (0, 0), (2, 2)] if d == 3 else [(0, 1), (0, 0)]
    out = []
    for i, j in pairs:
        e = np.zeros((d, d))
        e[i, j] += FD_STEP
        e[j, i] += FD_STEP
        out.append(e - np.trace(e) / d * np.eye(d))
    return out


def _fd_states(center: np.ndarray) -> list[np.ndarray]:
    out = []
    for e in fd_directions(center.shape[-1]):
        out += [center + e, center - e]
    return out


@functools.cache
def state_groups(d: int) -> dict[str, np.ndarray]:
    """Every test state of dimension ``d``, by group."""
    rot = rotation(d)
    rnd = random_a2(d, 6, seed=10 if d == 3 else 11)
    iso = np.eye(d) / d
    groups = {
        "random": rnd,
        "aligned": np.stack([np.outer(q, q) / (q @ q) for q in directions(d)]),
        "isotropic": iso[None],
        "rotated": (rot @ rnd[0] @ rot.T)[None],
        "fd_isotropic": np.stack(_fd_states(iso)),
        "fd_random": np.stack(_fd_states(rnd[0])),
    }
    if d == 3:
        # repeated eigenvalues a1 = a2 and a2 = a3, each also rotated (axes arbitrary there)
        deg = [np.diag([0.4, 0.4, 0.2]), np.diag([0.6, 0.2, 0.2])]
        groups["degenerate"] = np.stack(deg + [rot @ a @ rot.T for a in deg])
        groups["survey"] = random_a2(3, 40, seed=3)
        groups["jeffery"] = np.stack([a2 for a2, _, _ in jeffery_populations()])
        x = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
        groups["near_isotropic"] = np.stack([iso + eps * x for eps in NEAR_ISOTROPIC_EPS])
        # held-out states stored with the natural closure's fit, and planar states (a3 = 0)
        # where the exact closure is known in closed form (A_1122 = a1 a2 / 2)
        groups["natural_heldout"] = principal_states(NATURAL_FIT.HELDOUT_EIGENVALUES)
        groups["planar_in_3d"] = principal_states([(a, 1.0 - a, 0.0) for a in PLANAR_A1])
    else:
        groups["shear_population"] = planar_shear_population()[0][None]
        groups["planar_random"] = random_a2(2, 3, seed=7, n_vectors=50)
    return groups


def principal_states(values) -> np.ndarray:
    """Diagonal a2 with the given principal values, (n, 3, 3)."""
    return np.einsum("ni,ij->nij", np.asarray(values, dtype=np.float64), np.eye(3))


#: Largest principal value a1 of the ``planar_in_3d`` states (a2 = 1 - a1, a3 = 0); 0.943
#: is where the 3-D natural fit is worst on that edge.
PLANAR_A1 = (0.5, 0.7, 0.9, 0.943, 0.99)

#: Distances from isotropy of the ``near_isotropic`` group.
NEAR_ISOTROPIC_EPS = (0.0, 1e-14, 1e-9, 1e-6)


@functools.cache
def _layout(d: int):
    groups = state_groups(d)
    slices, start = {}, 0
    for name, arr in groups.items():
        slices[name] = slice(start, start + len(arr))
        start += len(arr)
    return np.concatenate(list(groups.values())), slices


def cotangent(d: int) -> np.ndarray:
    """The fixed weight W of the linear functional F(a2) = sum(f(a2) * W)."""
    return np.random.default_rng(11).normal(size=(d,) * 4)


class ClosureValues:
    """Values and gradients of one closure on every test state, by group."""

    def __init__(self, batch, a4, grads, a4_reversed, grads_reversed, slices):
        self.batch, self.a4, self.grads = batch, a4, grads
        # the second vmap member (same states, opposite order), put back in order
        self.a4_reversed, self.grads_reversed = a4_reversed, grads_reversed
        self._slices = slices

    def a2(self, group: str) -> np.ndarray:
        return self.batch[self._slices[group]]

    def __getitem__(self, group: str) -> np.ndarray:
        """a4 of the states of ``group``."""
        return self.a4[self._slices[group]]

    def grad(self, group: str) -> np.ndarray:
        return self.grads[self._slices[group]]

    def functional(self, group: str) -> np.ndarray:
        """F = sum(a4 * W) on the states of ``group``."""
        W = cotangent(self.batch.shape[-1])
        return np.einsum("...ijkl,ijkl->...", self[group], W)


#: Closures compiled in a program of their own (the expensive exact closure, kept apart
#: so that a failure there does not hide the others, and vice versa).
OWN_PROGRAM = ("fec",)


def _program_members(name: str, d: int) -> tuple[str, ...]:
    """Registered names compiled together with ``name``: either ``name`` alone, or every
    other closure of dimension ``d`` (one program compiles ~2x faster than one per
    closure, mostly through shared setup and common subexpressions such as the
    eigen-decomposition)."""
    if name in OWN_PROGRAM:
        return (name,)
    return tuple(n for n in C.available(d) if n not in OWN_PROGRAM)


@functools.cache
def _evaluate_program(members: tuple[str, ...], d: int) -> dict[str, ClosureValues]:
    batch, slices = _layout(d)
    W = jnp.asarray(cotangent(d))
    # aliases (e.g. "implicit_hybrid" is "sihyb") are evaluated once
    functions: dict[int, object] = {}
    for name in members:
        functions.setdefault(id(C.get_closure(name, d)), C.get_closure(name, d))
    unique = list(functions.values())

    def member(x):
        out = []
        for f in unique:
            a4, vjp = jax.vjp(f, x)
            (g,) = vjp(jnp.broadcast_to(W, a4.shape))
            out.append((a4, g))
        return out

    results = jax.jit(jax.vmap(member))(jnp.asarray(np.stack([batch, batch[::-1]])))
    by_function = {}
    for key, (a4, grads) in zip(functions, results):
        a4, grads = np.asarray(a4), np.asarray(grads)
        by_function[key] = ClosureValues(batch, a4[0], grads[0], a4[1][::-1], grads[1][::-1], slices)
    return {name: by_function[id(C.get_closure(name, d))] for name in members}


def closure_values(name: str, d: int) -> ClosureValues:
    """Closure ``name`` in dimension ``d`` on every test state (compiled on first use)."""
    return _evaluate_program(_program_members(name, d), d)[name]
