"""Social-force humans (Helbing & Molnar 1995; Helbing, Farkas & Vicsek 2000), batched.

Per unit mass, the acceleration of agent i is

    f_i = (v0_i - v_i) / tau + sum_j a * exp((r_i + r_j - d_ij) / b) * n_ji * w_ij

with v0_i the preferred velocity (goal - position, shortened to v_pref: the same as ORCA humans),
d_ij the distance between the centres, n_ji the unit vector from j to i and the anisotropy
w_ij = lam + (1 - lam) * (1 + cos phi_ij) / 2, where cos phi_ij = e_i . (-n_ji) compares i's
desired direction e_i = v0_i / |v0_i| with the direction towards j (Helbing & Johansson 2009;
lam = 1 is the isotropic force of Helbing et al. 2000). The velocity is integrated with one
explicit Euler step, v_i + f_i * dt, and capped at ``max_speed``. The world has no walls, so the
obstacle term of the papers is absent; standing humans play the part of obstacles.
"""

from __future__ import annotations

import numba
import numpy as np

from crowdplan.config import SocialForceConfig


@numba.njit(cache=True)
def _social_force_kernel(
    pos: np.ndarray,
    vel: np.ndarray,
    pref: np.ndarray,
    radius: np.ndarray,
    max_speed: np.ndarray,
    seen: np.ndarray,
    solve: np.ndarray,
    dt: float,
    tau: float,
    a: float,
    b: float,
    lam: float,
    out: np.ndarray,
) -> None:
    """Write the new velocity of every solved agent of every environment to ``out`` (E, M, 2)."""
    n_env, n_agents = pos.shape[0], pos.shape[1]
    for e in range(n_env):
        for i in range(n_agents):
            if not solve[e, i]:
                continue
            px, py = pos[e, i, 0], pos[e, i, 1]
            fx = (pref[e, i, 0] - vel[e, i, 0]) / tau
            fy = (pref[e, i, 1] - vel[e, i, 1]) / tau
            norm = np.sqrt(pref[e, i, 0] ** 2 + pref[e, i, 1] ** 2)
            ex, ey = 0.0, 0.0
            if norm > 0.0:
                ex, ey = pref[e, i, 0] / norm, pref[e, i, 1] / norm
            for j in range(n_agents):
                if j == i or not seen[e, j]:
                    continue
                dx, dy = px - pos[e, j, 0], py - pos[e, j, 1]
                d = np.sqrt(dx * dx + dy * dy)
                if d <= 0.0:
                    continue
                nx, ny = dx / d, dy / d
                cos_phi = -(ex * nx + ey * ny)
                w = lam + (1.0 - lam) * (1.0 + cos_phi) / 2.0
                mag = a * np.exp((radius[e, i] + radius[e, j] - d) / b) * w
                fx += mag * nx
                fy += mag * ny
            vx = vel[e, i, 0] + fx * dt
            vy = vel[e, i, 1] + fy * dt
            speed = np.sqrt(vx * vx + vy * vy)
            if speed > max_speed[e, i]:
                vx *= max_speed[e, i] / speed
                vy *= max_speed[e, i] / speed
            out[e, i, 0] = vx
            out[e, i, 1] = vy


def social_force_velocities(
    positions: np.ndarray,
    velocities: np.ndarray,
    preferred: np.ndarray,
    radii: np.ndarray,
    v_pref: np.ndarray,
    seen: np.ndarray,
    solve: np.ndarray,
    dt: float,
    params: SocialForceConfig | None = None,
) -> np.ndarray:
    """New velocities (E, M, 2) of the solved agents; the others keep ``velocities``.

    Args:
        positions, velocities, preferred: (E, M, 2) positions, current and preferred velocities.
        radii, v_pref: (E, M) body radii and preferred speeds (the cap is
            ``params.max_speed_factor * v_pref``).
        seen: (E, M) bool, the agent exerts a force on the others.
        solve: (E, M) bool, compute this agent's new velocity.
        dt: time step of the Euler integration.
    """
    params = params or SocialForceConfig()
    out = np.array(velocities, dtype=np.float64, copy=True)
    _social_force_kernel(
        np.ascontiguousarray(positions, dtype=np.float64),
        np.ascontiguousarray(velocities, dtype=np.float64),
        np.ascontiguousarray(preferred, dtype=np.float64),
        np.ascontiguousarray(radii, dtype=np.float64),
        np.ascontiguousarray(v_pref, dtype=np.float64) * params.max_speed_factor,
        np.ascontiguousarray(seen, dtype=np.bool_),
        np.ascontiguousarray(solve, dtype=np.bool_),
        float(dt),
        params.tau,
        params.a,
        params.b,
        params.lam,
        out,
    )
    return out
