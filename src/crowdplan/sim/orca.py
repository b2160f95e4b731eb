"""Batched ORCA (optimal reciprocal collision avoidance) for the humans of many environments.

Implements van den Berg, Guy, Lin and Manocha, "Reciprocal n-body collision avoidance" (2011):
every agent builds one half-plane of permitted velocities per neighbour (the ORCA constraint,
each agent taking half of the avoidance effort), then picks the velocity closest to its preferred
velocity inside those half-planes and the max-speed disc with an incremental 2-D linear program;
when that program is infeasible it falls back to the 3-D program that minimises the largest
penetration into any half-plane. There are no static obstacles.

One call equals one ``doStep()`` of the RVO2 library for the agents that are solved (verified by
``tests/test_orca_oracle.py`` against ``pyrvo``): neighbours are the ``max_neighbors`` closest
active agents within ``neighbor_dist`` in order of distance, lines are processed in that order and
the parallel-line tolerance is the same 1e-5. All environments and agents are solved by one
single-threaded Numba kernel with preallocated work arrays.

Known differences from RVO2: this module computes in float64 where RVO2 uses float32, so in
ill-conditioned programs (near-tangent agents, nearly parallel ORCA lines in the 3-D fallback;
about 1 agent-step in 1,000 in dense crowds) RVO2's answer differs by more than 1e-5, the float64
one being the accurate solution of the same program; two overlapping agents whose relative
velocity exactly cancels the 1/time_step cut-off get a push apart instead of RVO2's NaN; exact
distance ties between neighbours may be ordered differently from RVO2's k-d tree.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["orca_velocities", "preferred_velocities"]

# Tolerance for parallel lines, as in the paper's reference implementation.
EPSILON = 1e-5

# Kernel options: no division-by-zero checks (no division here can have a zero divisor; numpy's
# error model gives inf / nan like float arithmetic would, Python's raises and branches on every
# division), and the 2-D programs inlined into their callers (a call per agent otherwise).
_JIT = {"cache": True, "error_model": "numpy"}


@numba.njit(cache=True, inline="always")
def _det(ax: float, ay: float, bx: float, by: float) -> float:
    """2-D cross product (determinant of the 2x2 matrix with rows a and b)."""
    return ax * by - ay * bx


@numba.njit(**_JIT, inline="always")
def _lp1(
    pts: np.ndarray,
    dirs: np.ndarray,
    line_no: int,
    radius: float,
    opt_x: float,
    opt_y: float,
    direction_opt: bool,
) -> tuple[bool, float, float]:
    """Optimise along line ``line_no`` subject to lines ``0..line_no-1`` and the speed disc.

    Returns (feasible, x, y). With ``direction_opt`` the objective is the direction (opt_x, opt_y)
    (go as far as possible along it), otherwise the point closest to (opt_x, opt_y).
    """
    px = pts[line_no, 0]
    py = pts[line_no, 1]
    dx = dirs[line_no, 0]
    dy = dirs[line_no, 1]
    # The line meets the disc |v| <= radius on the parameter interval [t_left, t_right].
    along = px * dx + py * dy
    disc = along * along + radius * radius - (px * px + py * py)
    if disc < 0.0:
        return False, 0.0, 0.0
    root = np.sqrt(disc)
    t_left = -along - root
    t_right = -along + root

    for k in range(line_no):
        denom = _det(dx, dy, dirs[k, 0], dirs[k, 1])
        numer = _det(dirs[k, 0], dirs[k, 1], px - pts[k, 0], py - pts[k, 1])
        if abs(denom) <= EPSILON:
            # Parallel lines: either line_no lies wholly outside half-plane k, or k adds nothing.
            if numer < 0.0:
                return False, 0.0, 0.0
            continue
        t = numer / denom
        if denom >= 0.0:
            t_right = min(t_right, t)
        else:
            t_left = max(t_left, t)
        if t_left > t_right:
            return False, 0.0, 0.0

    if direction_opt:
        t = t_right if opt_x * dx + opt_y * dy > 0.0 else t_left
    else:
        t = dx * (opt_x - px) + dy * (opt_y - py)
        if t < t_left:
            t = t_left
        elif t > t_right:
            t = t_right
    return True, px + t * dx, py + t * dy


@numba.njit(**_JIT, inline="always")
def _lp2(
    pts: np.ndarray,
    dirs: np.ndarray,
    n_lines: int,
    radius: float,
    opt_x: float,
    opt_y: float,
    direction_opt: bool,
) -> tuple[int, float, float]:
    """Incremental 2-D linear program over lines ``0..n_lines-1`` inside the disc ``radius``.

    Returns (first failing line or n_lines on success, x, y); on failure (x, y) is the optimum
    of the lines before the failing one.
    """
    if direction_opt:
        # Objective is a unit direction: start at the disc boundary point along it.
        rx = opt_x * radius
        ry = opt_y * radius
    else:
        norm_sq = opt_x * opt_x + opt_y * opt_y
        if norm_sq > radius * radius:
            scale = radius / np.sqrt(norm_sq)
            rx = opt_x * scale
            ry = opt_y * scale
        else:
            rx = opt_x
            ry = opt_y

    for k in range(n_lines):
        # Only when the current optimum violates constraint k does it move onto line k.
        if _det(dirs[k, 0], dirs[k, 1], pts[k, 0] - rx, pts[k, 1] - ry) > 0.0:
            ok, x, y = _lp1(pts, dirs, k, radius, opt_x, opt_y, direction_opt)
            if not ok:
                return k, rx, ry
            rx = x
            ry = y
    return n_lines, rx, ry


@numba.njit(**_JIT)
def _lp3(
    pts: np.ndarray,
    dirs: np.ndarray,
    n_lines: int,
    begin: int,
    radius: float,
    rx: float,
    ry: float,
    proj_pts: np.ndarray,
    proj_dirs: np.ndarray,
) -> tuple[float, float]:
    """3-D fallback: minimise the largest signed distance into the violated half-planes.

    Lines from ``begin`` on are processed incrementally; for each violated one, the earlier lines
    are projected onto it (bisectors between line k and each earlier line) and a 2-D program in the
    direction perpendicular to line k is solved.
    """
    distance = 0.0
    for k in range(begin, n_lines):
        kx = dirs[k, 0]
        ky = dirs[k, 1]
        if _det(kx, ky, pts[k, 0] - rx, pts[k, 1] - ry) > distance:
            n_proj = 0
            for m in range(k):
                mx = dirs[m, 0]
                my = dirs[m, 1]
                denom = _det(kx, ky, mx, my)
                if abs(denom) <= EPSILON:
                    if kx * mx + ky * my > 0.0:
                        # Same direction: line m's constraint is implied or irrelevant here.
                        continue
                    # Opposite directions: the bisector lies midway between the two lines.
                    qx = 0.5 * (pts[k, 0] + pts[m, 0])
                    qy = 0.5 * (pts[k, 1] + pts[m, 1])
                else:
                    s = _det(mx, my, pts[k, 0] - pts[m, 0], pts[k, 1] - pts[m, 1]) / denom
                    qx = pts[k, 0] + s * kx
                    qy = pts[k, 1] + s * ky
                bx = mx - kx
                by = my - ky
                blen = np.sqrt(bx * bx + by * by)
                proj_pts[n_proj, 0] = qx
                proj_pts[n_proj, 1] = qy
                proj_dirs[n_proj, 0] = bx / blen
                proj_dirs[n_proj, 1] = by / blen
                n_proj += 1

            fail, x, y = _lp2(proj_pts, proj_dirs, n_proj, radius, -ky, kx, True)
            # A failure here can only come from rounding; then keep the previous result.
            if fail >= n_proj:
                rx = x
                ry = y
            distance = _det(kx, ky, pts[k, 0] - rx, pts[k, 1] - ry)
    return rx, ry


@numba.njit(**_JIT)
def _orca_kernel(
    pos: np.ndarray,
    vel: np.ndarray,
    rad: np.ndarray,
    pref: np.ndarray,
    vmax: np.ndarray,
    active: np.ndarray,
    solve: np.ndarray,
    time_step: float,
    neighbor_dist: float,
    max_neighbors: int,
    time_horizon: float,
    out: np.ndarray,
) -> None:
    """Fill ``out`` (E, M, 2) with the new velocity of every solved agent of every environment."""
    n_env, n_agents = pos.shape[0], pos.shape[1]
    cap = max(max_neighbors, 1)
    nb_idx = np.empty(cap, dtype=np.int64)
    # Work arrays follow the input dtype so that the pure-Python version of this kernel
    # (``_orca_kernel.py_func``) run on float32 inputs evaluates everything in float32.
    nb_dsq = np.empty(cap, dtype=pos.dtype)
    pts = np.empty((cap, 2), dtype=pos.dtype)
    dirs = np.empty((cap, 2), dtype=pos.dtype)
    proj_pts = np.empty((cap, 2), dtype=pos.dtype)
    proj_dirs = np.empty((cap, 2), dtype=pos.dtype)
    inv_tau = 1.0 / time_horizon
    inv_dt = 1.0 / time_step
    range_sq0 = neighbor_dist * neighbor_dist

    for e in range(n_env):
        for i in range(n_agents):
            vx = vel[e, i, 0]
            vy = vel[e, i, 1]
            if not solve[e, i]:
                out[e, i, 0] = vx
                out[e, i, 1] = vy
                continue
            px = pos[e, i, 0]
            py = pos[e, i, 1]

            # Neighbours: the max_neighbors closest active agents within neighbor_dist, sorted by
            # distance; once the list is full, the search radius shrinks to its farthest entry.
            count = 0
            if max_neighbors > 0:
                range_sq = range_sq0
                for j in range(n_agents):
                    if j == i or not active[e, j]:
                        continue
                    ddx = pos[e, j, 0] - px
                    ddy = pos[e, j, 1] - py
                    dsq = ddx * ddx + ddy * ddy
                    if dsq >= range_sq:
                        continue
                    if count < max_neighbors:
                        count += 1
                    k = count - 1
                    while k > 0 and dsq < nb_dsq[k - 1]:
                        nb_dsq[k] = nb_dsq[k - 1]
                        nb_idx[k] = nb_idx[k - 1]
                        k -= 1
                    nb_dsq[k] = dsq
                    nb_idx[k] = j
                    if count == max_neighbors:
                        range_sq = nb_dsq[count - 1]

            # One ORCA half-plane per neighbour: permitted velocities lie left of the directed
            # line through pts[n] along dirs[n].
            for n in range(count):
                j = nb_idx[n]
                rel_px = pos[e, j, 0] - px
                rel_py = pos[e, j, 1] - py
                rel_vx = vx - vel[e, j, 0]
                rel_vy = vy - vel[e, j, 1]
                dist_sq = rel_px * rel_px + rel_py * rel_py
                r_sum = rad[e, i] + rad[e, j]
                r_sum_sq = r_sum * r_sum

                if dist_sq > r_sum_sq:
                    # Velocity obstacle truncated at time_horizon: a cone with a circular cap of
                    # radius r_sum / tau centred at rel_p / tau. w: relative velocity seen from
                    # that cap centre.
                    wx = rel_vx - inv_tau * rel_px
                    wy = rel_vy - inv_tau * rel_py
                    w_sq = wx * wx + wy * wy
                    w_dot_p = wx * rel_px + wy * rel_py
                    if w_dot_p < 0.0 and w_dot_p * w_dot_p > r_sum_sq * w_sq:
                        # Closest boundary point is on the cap.
                        w_len = np.sqrt(w_sq)
                        ux_ = wx / w_len
                        uy_ = wy / w_len
                        dirs[n, 0] = uy_
                        dirs[n, 1] = -ux_
                        scale = r_sum * inv_tau - w_len
                        ux = scale * ux_
                        uy = scale * uy_
                    else:
                        # Closest boundary point is on one of the two legs of the cone.
                        leg = np.sqrt(dist_sq - r_sum_sq)
                        if _det(rel_px, rel_py, wx, wy) > 0.0:
                            # Left leg.
                            dxl = (rel_px * leg - rel_py * r_sum) / dist_sq
                            dyl = (rel_px * r_sum + rel_py * leg) / dist_sq
                        else:
                            # Right leg, directed so that the permitted side is on the left.
                            dxl = -(rel_px * leg + rel_py * r_sum) / dist_sq
                            dyl = -(-rel_px * r_sum + rel_py * leg) / dist_sq
                        dirs[n, 0] = dxl
                        dirs[n, 1] = dyl
                        proj = rel_vx * dxl + rel_vy * dyl
                        ux = proj * dxl - rel_vx
                        uy = proj * dyl - rel_vy
                else:
                    # Already overlapping: resolve within one time step (cap of radius r_sum / dt
                    # centred at rel_p / dt).
                    wx = rel_vx - inv_dt * rel_px
                    wy = rel_vy - inv_dt * rel_py
                    w_len = np.sqrt(wx * wx + wy * wy)
                    if w_len > 0.0:
                        ux_ = wx / w_len
                        uy_ = wy / w_len
                    else:
                        # Degenerate (RVO2 yields NaN here): push straight away from the
                        # neighbour, or along +-x for coincident centres.
                        p_len = np.sqrt(dist_sq)
                        if p_len > 0.0:
                            ux_ = -rel_px / p_len
                            uy_ = -rel_py / p_len
                        else:
                            ux_ = 1.0 if i < j else -1.0
                            uy_ = 0.0
                    dirs[n, 0] = uy_
                    dirs[n, 1] = -ux_
                    scale = r_sum * inv_dt - w_len
                    ux = scale * ux_
                    uy = scale * uy_

                # Reciprocity: this agent takes half of the smallest change u.
                pts[n, 0] = vx + 0.5 * ux
                pts[n, 1] = vy + 0.5 * uy

            speed = vmax[e, i]
            fail, nx, ny = _lp2(pts, dirs, count, speed, pref[e, i, 0], pref[e, i, 1], False)
            if fail < count:
                nx, ny = _lp3(pts, dirs, count, fail, speed, nx, ny, proj_pts, proj_dirs)
            out[e, i, 0] = nx
            out[e, i, 1] = ny


def _as_array(x: np.ndarray | float | bool, dtype: type, shape: tuple[int, ...]) -> np.ndarray:
    """``x`` as a C-contiguous array of ``dtype`` and ``shape`` (broadcasting only if needed)."""
    arr = np.asarray(x, dtype=dtype)
    if arr.shape != shape:
        arr = np.broadcast_to(arr, shape)
    return np.ascontiguousarray(arr)


def orca_velocities(
    positions: np.ndarray,
    velocities: np.ndarray,
    radii: np.ndarray | float,
    pref_velocities: np.ndarray,
    max_speeds: np.ndarray | float,
    active: np.ndarray | bool,
    solve: np.ndarray | bool,
    time_step: float,
    neighbor_dist: float = 10.0,
    max_neighbors: int = 10,
    time_horizon: float = 5.0,
) -> np.ndarray:
    """New ORCA velocities of all solved agents of E environments (one RVO2 ``doStep``).

    Args:
        positions: (E, M, 2) agent positions.
        velocities: (E, M, 2) current agent velocities.
        radii: (E, M) radii used by ORCA (the caller adds any safety pad, e.g. r + 0.01).
        pref_velocities: (E, M, 2) preferred velocities.
        max_speeds: (E, M) maximum speeds.
        active: (E, M) bool, the agent exists and is seen by the others as a neighbour.
        solve: (E, M) bool, compute a new velocity for this agent (an inactive agent may be
            solved too: it avoids the active ones without being avoided).
        The (E, M) arguments may be anything that broadcasts to (E, M), e.g. a scalar.
        time_step: simulation step dt (used when two agents already overlap).
        neighbor_dist: only agents closer than this are neighbours.
        max_neighbors: at most this many (closest) neighbours are considered.
        time_horizon: ORCA time horizon tau.

    Returns:
        (E, M, 2) float64 new velocities; rows with ``solve`` False equal ``velocities``.
        Positions are not advanced (the caller integrates ``position + dt * velocity``).
    """
    pos = np.ascontiguousarray(positions, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[2] != 2:
        raise ValueError(f"positions must be (E, M, 2); got {pos.shape}")
    shape = pos.shape[:2]
    vel = _as_array(velocities, np.float64, pos.shape)
    pref = _as_array(pref_velocities, np.float64, pos.shape)
    rad = _as_array(radii, np.float64, shape)
    vmax = _as_array(max_speeds, np.float64, shape)
    act = _as_array(active, np.bool_, shape)
    sol = _as_array(solve, np.bool_, shape)
    if time_step <= 0.0 or time_horizon <= 0.0:
        raise ValueError("time_step and time_horizon must be positive")
    out = np.empty_like(vel)
    _orca_kernel(
        pos,
        vel,
        rad,
        pref,
        vmax,
        act,
        sol,
        float(time_step),
        float(neighbor_dist),
        int(max_neighbors),
        float(time_horizon),
        out,
    )
    return out


def preferred_velocities(
    positions: np.ndarray, goals: np.ndarray, speeds: np.ndarray | float
) -> np.ndarray:
    """Goal-directed preferred velocities: ``goal - position``, shortened to ``speed`` if longer.

    Args:
        positions: (..., 2) agent positions.
        goals: (..., 2) agent goals.
        speeds: (...) preferred speeds (or a scalar); with speed 1 this is CrowdNav's rule
            "scaled to unit length when longer than 1".

    Returns:
        (..., 2) float64 preferred velocities.
    """
    v = np.asarray(goals, dtype=np.float64) - np.asarray(positions, dtype=np.float64)
    speed = np.asarray(speeds, dtype=np.float64)
    norm = np.linalg.norm(v, axis=-1)
    scale = np.where(norm > speed, speed / np.where(norm > 0.0, norm, 1.0), 1.0)
    return v * scale[..., None]
