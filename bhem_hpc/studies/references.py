"""Independent reference solutions used by validation tests and jobs (numpy only).

* Kirchhoff plates under uniform load (small deflection): Navier's series for a simply
  supported square plate, the tabulated value for a clamped one.
* The heavy elastica: a cantilever under its own weight (Romero et al. 2021, the master curve of
  the paper's Fig. 19), solved by shooting on the exact rod equations.
"""

from __future__ import annotations

import functools
import math

import numpy as np

# Centre deflection of a clamped square plate, w D / (q a^4) (Taylor & Govindjee 2004).
CLAMPED_SQUARE_PLATE = 0.00126532
#: Scordelis-Lo roof, Kirchhoff-Love theory: midside deflection of the free edge (Kiendl et al. 2009).
ROOF_DEFLECTION = 0.3006


def simply_supported_square_plate(terms: int = 401) -> float:
    """Centre deflection ``w D / (q a^4)`` of a simply supported square plate (Navier series).

    ``w = 16 q / (pi^6 D) sum_{m,n odd} sin(m pi/2) sin(n pi/2) / (m n (m^2 + n^2)^2)``; with
    ``terms`` odd indices per direction the truncation error is below 1e-12 relative.
    """
    odd = np.arange(1, 2 * terms, 2, dtype=float)
    m, n = np.meshgrid(odd, odd, indexing="ij")
    signs = np.sin(m * np.pi / 2) * np.sin(n * np.pi / 2)
    return float(16 / np.pi**6 * np.sum(signs / (m * n * (m**2 + n**2) ** 2)))


def _integrate_from_tip(
    gamma: float, tip_tilt: float, steps: int, path: list[tuple[float, float]] | None = None
) -> tuple[float, float, float]:
    """RK4 from the free end towards the clamp, in ``t = 1 - s``.

    Unknown: ``psi = pi/2 - theta``, the angle from the vertical. ``d2 psi/dt2 = gamma t sin(psi)``,
    ``psi(0) = tip_tilt``, ``dpsi/dt(0) = 0`` (no moment at the free end), with
    ``W = int sin(psi)`` and ``H = int cos(psi)``. Near the vertical ``psi`` grows like an Airy
    function, so the tip tilt of a heavy rod is tiny: working in ``psi`` keeps it representable.

    Returns:
        ``(psi at the clamp, W / L, H / L)``; ``path`` (if given) receives the points
        ``(x, y)`` of the rod relative to the tip, from the tip to the clamp.
    """
    cos, sin = math.cos, math.sin

    def rhs(t: float, y: list[float]) -> list[float]:
        return [y[1], gamma * t * sin(y[0]), sin(y[0]), cos(y[0])]

    h = 1.0 / steps
    y = [tip_tilt, 0.0, 0.0, 0.0]
    if path is not None:
        path.append((0.0, 0.0))
    for i in range(steps):
        t = i * h
        k1 = rhs(t, y)
        k2 = rhs(t + h / 2, [a + h / 2 * b for a, b in zip(y, k1, strict=False)])
        k3 = rhs(t + h / 2, [a + h / 2 * b for a, b in zip(y, k2, strict=False)])
        k4 = rhs(t + h, [a + h * b for a, b in zip(y, k3, strict=False)])
        y = [a + h / 6 * (b + 2 * c + 2 * d + e) for a, b, c, d, e in zip(y, k1, k2, k3, k4, strict=False)]
        if path is not None:
            path.append((-y[2], y[3]))
    return y[0], y[2], y[3]


def heavy_cantilever_tip(gamma: float, steps: int = 1000) -> tuple[float, float]:
    """Tip ``(W / L, H / L)`` of the heavy elastica; see :func:`heavy_cantilever`."""
    return heavy_cantilever(gamma, steps)[:2]


def heavy_cantilever(gamma: float, steps: int = 1000) -> tuple[float, float, np.ndarray]:
    """Tip of a horizontally clamped cantilever under self-weight (the heavy elastica).

    ``theta'' = -gamma (1 - s) cos(theta)`` with ``theta(0) = 0`` (clamp) and ``theta'(1) = 0``
    (free end). Shooting from the clamp is ill-conditioned at large ``gamma``; we shoot from
    the free end on its tilt from the vertical, ``psi_tip``. The clamp angle is not monotone in
    ``psi_tip`` (large tilts give looping rods), so the physical root - the smallest tilt at which
    the rod reaches the horizontal at the clamp - is bracketed by a logarithmic scan and refined by
    bisection in ``log(psi_tip)``.

    Args:
        gamma: ``Gamma* = 12 (1 - nu^2) rho g L^3 / (Y h^2)`` (= ``w L^3 / D`` per unit width).
        steps: RK4 steps along the rod (error ~ steps^-4).

    Returns:
        ``(W / L, H / L, shape)``: horizontal extent and drop of the tip (master curve:
        ``H / W``) and the rod's shape ``(steps + 1, 2)`` as ``(x / L, z / L)`` from the clamp
        (z up, so the tip is at ``(W, -H)``).
    """
    if not (isinstance(gamma, int | float) and math.isfinite(gamma) and 0 < gamma <= 1e6):
        raise ValueError(f"gamma must be a number in (0, 1e6], got {gamma!r}")

    def mismatch(log_tilt: float) -> float:
        return _integrate_from_tip(gamma, math.exp(log_tilt), steps)[0] - math.pi / 2

    grid = np.linspace(math.log(1e-300), math.log(math.pi / 2), 200)
    lo = grid[0]
    if mismatch(lo) >= 0:
        raise RuntimeError(f"heavy elastica: no bracket at gamma = {gamma}")
    for hi in grid[1:]:
        if mismatch(hi) >= 0:
            break
        lo = hi
    else:
        raise RuntimeError(f"heavy elastica: no root at gamma = {gamma}")
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mismatch(mid) >= 0:
            hi = mid
        else:
            lo = mid
        if hi - lo < 1e-15 * max(1.0, abs(lo)):
            break
    path: list[tuple[float, float]] = []
    _, width, height = _integrate_from_tip(gamma, math.exp(0.5 * (lo + hi)), steps, path)
    # The path runs tip -> clamp relative to the tip; put the clamp at the origin, tip last.
    shape = np.array(path[::-1]) - np.array([-width, height])
    return width, height, shape


@functools.cache
def lateral_buckling_constant(steps: int = 1000) -> float:
    """The eigenvalue ``lambda`` of lateral-torsional buckling of a cantilever under a uniform load
    at its centroid (Michell-Prandtl): ``(q L^3)_cr = lambda sqrt(B C)`` with ``B`` the weak-axis
    bending and ``C`` the torsional stiffness (Timoshenko & Gere tabulate 12.85).

    The twist obeys ``phi'' + lambda^2 (1 - s)^4 / 4 phi = 0`` on ``s in [0, 1]`` (clamped:
    ``phi(0) = 0``; free: ``phi'(1) = 0``): RK4 shooting, bisection on the first root of ``phi'(1)``.
    """

    def end_slope(lam: float) -> float:
        h = 1.0 / steps
        y = np.array([0.0, 1.0])

        def f(s: float, y: np.ndarray) -> np.ndarray:
            return np.array([y[1], -(lam**2) * (1 - s) ** 4 / 4 * y[0]])

        s = 0.0
        for _ in range(steps):
            k1 = f(s, y)
            k2 = f(s + h / 2, y + h / 2 * k1)
            k3 = f(s + h / 2, y + h / 2 * k2)
            k4 = f(s + h, y + h * k3)
            y = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            s += h
        return float(y[1])

    low, high = 1.0, 1.0
    while end_slope(high) > 0:  # phi'(1) = 1 at lambda = 0 and first changes sign at the eigenvalue
        low, high = high, 1.5 * high
    for _ in range(60):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if end_slope(mid) > 0 else (low, mid)
    return 0.5 * (low + high)


def lateral_buckling_gamma(poisson: float) -> float:
    """Critical ``Gamma* = 12 (1 - nu^2) rho g L^3 / (Y h^2)`` of a thin strip hanging on edge from a
    clamp (width vertical, in its plane; the narrow-strip limit ``h << w << L``).

    The strip's weight per length is ``q = rho g h w``; out of its plane it bends with
    ``B = D w = Y h^3 w / (12 (1 - nu^2))`` (the plate stiffness, as the clamp and the shell's
    kinematics hold the section) and twists with ``C = Y h^3 w / (6 (1 + nu))``; then
    ``rho g L^3 / (Y h^2) = lambda / sqrt(72 (1 - nu^2)(1 + nu))`` and ``w`` drops out.
    """
    lam = lateral_buckling_constant()
    return 12 * (1 - poisson**2) * lam / math.sqrt(72 * (1 - poisson**2) * (1 + poisson))


def shallow_arch_load(rise: np.ndarray | float, initial_rise: float) -> np.ndarray | float:
    """Load ``P = p L^4 / (pi^4 EI r)`` of a pinned shallow sinusoidal arch under the sinusoidal load
    ``p sin(pi x / L)`` (downward, per length), at midspan rise ``xi = a / r`` (``r`` the radius of
    gyration, ``a`` the current rise, ``initial_rise`` = ``e / r``).

    Marguerre's shallow-arch equations with the rest shape ``e sin(pi x / L)`` keep the symmetric
    path in that one mode exactly: the axial force ``N = EA pi^2 (a^2 - e^2) / (4 L^2)`` is constant
    and stationarity of ``EI (pi/L)^4 (a - e)^2 L / 4 + EA L (pi/L)^4 (a^2 - e^2)^2 / 32 + p a L / 2``
    gives ``P = (e - xi) + xi (e^2 - xi^2) / 4`` (in units of ``r``). Limit points at
    ``xi^2 = (e^2 - 4) / 3`` for ``e > 2``; the antisymmetric mode never bifurcates from the path
    while ``e^2 < 22``. Its error against a geometrically exact shell is of the order of the
    squared slope ``(pi e / L)^2``.
    """
    xi = np.asarray(rise, dtype=float)
    return (initial_rise - xi) + xi * (initial_rise**2 - xi**2) / 4


def complete_elliptic_integrals(k: float) -> tuple[float, float]:
    """``K(k)`` and ``E(k)`` (modulus ``k``, ``0 <= k < 1``) by the arithmetic-geometric mean, to
    round-off (Abramowitz & Stegun 17.6)."""
    a, b, c2_sum, power = 1.0, math.sqrt(1.0 - k * k), k * k / 2, 0.5
    for _ in range(60):
        if abs(a - b) <= 1e-16 * a:
            break
        c = (a - b) / 2
        a, b = (a + b) / 2, math.sqrt(a * b)
        power *= 2
        c2_sum += power * c * c
    elliptic_k = math.pi / (2 * a)
    return elliptic_k, elliptic_k * (1 - c2_sum)


def pinned_elastica(deflection: float) -> tuple[float, float]:
    """The Euler elastica of a strut pinned at both ends: at midspan deflection ``w / L`` its load
    ``P / P_cr`` and end shortening ``Delta / L``.

    With ``k = sin(alpha / 2)`` (``alpha`` the end rotation): ``P / P_cr = (2 K(k) / pi)^2``,
    ``w / L = k / K(k)``, ``Delta / L = 2 (1 - E(k) / K(k))``; ``k`` by bisection (``w / L`` up to 0.39).
    """
    if not 0 <= deflection <= 0.39:
        raise ValueError(f"midspan deflection w / L = {deflection!r} outside [0, 0.39]")
    low, high = 0.0, 0.95
    for _ in range(200):
        k = (low + high) / 2
        low, high = (k, high) if k / complete_elliptic_integrals(k)[0] < deflection else (low, k)
    k = (low + high) / 2
    elliptic_k, elliptic_e = complete_elliptic_integrals(k)
    return (2 * elliptic_k / math.pi) ** 2, 2 * (1 - elliptic_e / elliptic_k)
