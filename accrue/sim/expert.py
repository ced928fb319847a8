"""Scripted search-and-insert experts that act from the observation only.

Align over the (bias-corrected) socket estimate, descend, and when the plug sits on the socket
without sinking, follow the wrist force laterally and spiral outward with a small yaw wiggle
until it drops in. The wide search (default where a task declares per-episode aim errors beyond
the narrow 1.3 mm / 4 degree reach: the contact family) reaches 2.5 sigma of those errors, sweeps yaw
slowly enough to follow, twists a part jammed inside the hole (rotation under contact) and slides over the
surface with a light touch (compliance: pressed hard, friction pins the plug). `quality` < 1 adds a per-episode aim error and per-step action noise, so
demonstration sets of mixed quality can be drawn.

`search=False` gives the demonstrator who aligns, descends and pushes but never searches: every action is
a function of the current observation alone (no memory of being stuck), which a policy can imitate from
single observations. It succeeds only when the socket estimate is close enough for the chamfer to guide the
plug in (with bias_known 0.75: 0.39 / 0.27 / 0.33 of rect_peg / round_peg / gear episodes, measured by
`scripts/base_policy_table.py --expert-episodes`), leaving RL the rest. `bias_known` is the fraction of its fixture's estimate bias the demonstrator corrects (1 = all of it).
"""

from __future__ import annotations

import numpy as np

from accrue.sim.observation import decode_state, rotate_xy
from accrue.sim.tasks import DEG, MM, TaskSpec, get_task

CONTACT_FORCE = 1.5  # N of |Fz| above which the plug is taken to rest on something
LIGHT_PRESS = 3.0  # N of |Fz| the wide search presses with while it slides over the surface
NARROW_XY, NARROW_YAW = 1.3 * MM, 4 * DEG  # the narrow search's reach (the nist/plugs expert's)
ENTERED = 1.2 * MM  # tip this far below the socket top: past the chamfer, inside the hole


def _wrap(a, period):
    return (a + period / 2) % period - period / 2


class ScriptedExpert:
    def __init__(
        self,
        task: TaskSpec,
        quality: float = 1.0,
        seed: int = 0,
        correction=None,
        search: bool = True,
        bias_known: float = 1.0,
        wide: bool | None = None,
    ):
        self.task, self.quality, self.search = task, float(np.clip(quality, 0.0, 1.0)), bool(search)
        bx, by, byaw = task.estimate_bias
        # what a demonstrator who knows (the fraction bias_known of) this fixture adds to the estimate
        known = -bias_known * np.array([bx, by, byaw])
        self.correction = np.array(known if correction is None else correction, dtype=float)
        self.rng = np.random.default_rng(seed)
        self._n = 0
        # the search's reach: 1.3 mm / 4 degrees, or in the wide search 2.5 sigma of the aim errors the task
        # declares (estimate + in-hand offset); wide=None: wide where those exceed the narrow reach
        r = task.randomisation
        reach_xy = max(NARROW_XY, 2.5 * float(np.hypot(r.estimate_xy, r.in_hand_xy)))
        reach_yaw = max(NARROW_YAW, 2.5 * float(np.hypot(r.estimate_yaw, r.in_hand_yaw)))
        self.wide = bool((reach_xy > NARROW_XY or reach_yaw > NARROW_YAW) if wide is None else wide)
        self.reach_xy, self.reach_yaw = (reach_xy, reach_yaw) if self.wide else (NARROW_XY, NARROW_YAW)
        # a yaw sweep slow enough for the rotation rate limit to follow (narrow: 1.3 rad per step)
        self.yaw_rate = min(1.3, 0.7 * task.max_delta_rot / self.reach_yaw) if self.wide else 1.3

    def _ensure(self, n: int) -> None:
        if self._n != n:
            self._n = n
            self.aim = np.zeros((n, 3))
            self.stuck = np.zeros(n, dtype=np.int64)
            self.last_z = np.full(n, np.inf)
            self.shift = np.zeros((n, 2))

    def _new_episode(self, i: int) -> None:
        spread = 1.0 - self.quality
        ang = self.rng.uniform(0, 2 * np.pi)
        self.aim[i] = [
            spread * 0.9 * MM * np.cos(ang),
            spread * 0.9 * MM * np.sin(ang),
            spread * self.rng.choice([-1, 1]) * 2.5 * DEG,
        ]
        self.stuck[i], self.last_z[i], self.shift[i] = 0, np.inf, 0.0

    def act(self, state: np.ndarray) -> np.ndarray:
        state = np.atleast_2d(np.asarray(state))
        n = len(state)
        self._ensure(n)
        d = decode_state(state)
        for i in np.flatnonzero(d["time_frac"] <= 1e-9):
            self._new_episode(int(i))
        if not self.search:  # no memory: never counts itself stuck, never spirals or shifts
            self.stuck[:], self.last_z[:], self.shift[:] = 0, np.inf, 0.0
        task = self.task
        goal_xy = d["est_pos"][:, :2] + self.correction[:2] + self.aim[:, :2]
        goal_yaw = d["est_yaw"] + self.correction[2] + self.aim[:, 2]
        pos, yaw = d["pos"], d["yaw"]
        z = pos[:, 2] - d["est_pos"][:, 2]
        force_r = np.column_stack([rotate_xy(d["force"][:, :2], yaw), d["force"][:, 2]])
        touching = np.abs(force_r[:, 2]) > CONTACT_FORCE
        sinking = z < self.last_z - 0.3 * MM  # well above the per-step position noise
        self.last_z = z
        inside = z < -ENTERED
        blocked = touching & ~sinking
        self.stuck = np.where(blocked, self.stuck + 1, np.where(sinking, 0, self.stuck))
        # admittance: yield to the lateral contact force (the sensor reads the plug's reaction)
        lateral = -force_r[:, :2] * 0.08 * MM
        self.shift = np.clip(self.shift + np.where(blocked[:, None] & ~inside[:, None], lateral, 0.0), -MM, MM)
        k = np.where(inside, 0, self.stuck)
        rings = int(round(self.reach_xy / (0.1 * MM))) + 1
        radius = 0.1 * MM * (k % rings)  # spiral out to reach_xy (1.3 mm at least), then start over
        theta = 0.9 * k
        spiral = np.column_stack([radius * np.cos(theta), radius * np.sin(theta)])
        period = task.yaw_period
        # rotation under contact: the wide search also twists a part jammed inside the hole (a gear on its
        # shaft, blocked by the neighbour's teeth); the narrow one only twists outside
        ky = self.stuck if self.wide else k
        # widen the yaw search as it drags on, reaching reach_yaw after 16 stuck steps (narrow: 0.25 deg/step)
        amplitude = np.minimum(0.8 * DEG + self.reach_yaw / 16 * ky, self.reach_yaw)
        wiggle = np.where(ky > 0, amplitude * np.sin(self.yaw_rate * ky), 0.0) if period > 0 else 0.0
        yaw_err = _wrap(goal_yaw + wiggle - yaw, period) if period > 0 else np.zeros(n)

        # outside: servo onto the (searched) goal; inside: comply with the walls, unjam by lifting
        xy_err = np.where(inside[:, None], lateral, goal_xy + spiral + self.shift - pos[:, :2])
        aligned = (np.hypot(*xy_err.T) < 0.4 * MM) & (np.abs(yaw_err) < 1.5 * DEG)
        high = z > 3 * MM
        every = 12 if self.wide else 4  # the wide search twists longer before a lift resets it
        jammed = inside & (self.stuck > 0) & (self.stuck % every == 0)
        dz = np.where(high, np.where(aligned, -1.0, -0.4), np.where(aligned | inside | (k > 0), -0.6, 0.0))
        dz = np.where(jammed, 0.5, dz)
        if self.wide:  # search with a light touch, or friction pins the plug where it landed (compliance)
            dz = np.where(~inside & (k > 0), np.where(np.abs(force_r[:, 2]) > LIGHT_PRESS, 0.25, -0.25), dz)
        act = np.zeros((n, 6))
        act[:, :2] = xy_err / task.max_delta_pos
        act[:, 2] = dz
        act[:, 3:5] = -d["tilt"] / task.max_delta_rot
        act[:, 5] = yaw_err / task.max_delta_rot
        if self.quality < 1.0:
            act += self.rng.normal(0.0, 0.35 * (1.0 - self.quality), act.shape)
        return np.clip(act, -1.0, 1.0).astype(np.float32)


def expert_success_rate(task_id: str, episodes: int, seed: int = 0, quality: float = 1.0, **expert_kw) -> float:
    """Success of the scripted expert over `episodes` parallel episodes (one per env), acting every control
    step; expert_kw go to make_expert (correction, search, bias_known, wide)."""
    from accrue.sim.vec_env import make_vec_env

    env = make_vec_env(task_id, num_envs=episodes, seed=seed)
    expert = make_expert(task_id, quality, seed=seed, **expert_kw)
    obs, won, done = env.reset(), np.zeros(episodes, bool), np.zeros(episodes, bool)
    while not done.all():
        res = env.step(expert.act(obs["state"]))
        won |= res.success & ~done
        done |= res.done
        obs = res.obs
    env.close()
    return float(won.mean())


def make_expert(
    task_id: str | TaskSpec,
    quality: float = 1.0,
    seed: int = 0,
    correction=None,
    search: bool = True,
    bias_known: float = 1.0,
    wide: bool | None = None,
) -> ScriptedExpert:
    task = get_task(task_id) if isinstance(task_id, str) else task_id
    return ScriptedExpert(
        task, quality=quality, seed=seed, correction=correction, search=search, bias_known=bias_known, wide=wide
    )
