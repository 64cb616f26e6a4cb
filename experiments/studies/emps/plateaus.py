"""The friction a record shows where nothing else acts: its constant-speed plateaus, per cycle.

On a plateau of the reference (constant speed, no acceleration) the mean measured force is the
friction at that speed plus the constant force (cogging averages out over the plateau's many
periods). Per cycle of the program and per direction, a straight line through the plateaus'
(mean measured speed, mean force) points gives the friction's intercept (Coulomb plus the
constant force, N) and slope (viscous, N·s/m); the mean of the two directions' slopes is the
symmetric viscous friction, half their difference the direction-odd part. A model fitted on a
record assumes these are stationary; the table shows whether the record itself agrees, from the
training record alone, model-free.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clm_sim.run import Run


@dataclass(frozen=True)
class Plateau:
    """One constant-speed stretch: start (s), cycle index, mean speed (m/s), mean force (N)."""

    t_s: float
    cycle: int
    speed: float
    force_n: float


@dataclass(frozen=True)
class CycleFriction:
    """Per direction, the line ``force = intercept + slope * speed`` through one cycle's
    plateaus: intercepts (N) and slopes (N·s/m), upward (+) and downward (−), and the largest
    distance (N) of a plateau from its line (friction not affine in speed, or depending on
    where in the stroke the plateau lies, shows there)."""

    cycle: int
    intercept_up: float
    slope_up: float
    intercept_down: float
    slope_down: float
    off_line_n: float = 0.0

    @property
    def viscous(self) -> float:
        """Symmetric viscous friction (N·s/m): the mean of the two slopes."""
        return (self.slope_up + self.slope_down) / 2

    @property
    def viscous_odd(self) -> float:
        """Direction-odd viscous part (N·s/m): half the upward minus the downward slope."""
        return (self.slope_up - self.slope_down) / 2


def plateaus(run: Run, edges: tuple[int, ...], min_samples: int = 200) -> list[Plateau]:
    """The reference's constant-speed stretches of at least ``min_samples`` samples; on each,
    the mean force and the measured speed over its 30 %–90 % part (the loop has settled)."""
    v = np.diff(run.r) / run.ts
    step = max(float(np.abs(v).max()) * 1e-6, 1e-12)
    level = np.round(v / step)
    change = np.flatnonzero(np.diff(level) != 0) + 1
    out = []
    for a, b in zip(np.r_[0, change], np.r_[change, len(v)]):
        if b - a < min_samples or level[a] == 0:
            continue
        i, j = a + int(0.3 * (b - a)), a + int(0.9 * (b - a))
        cycle = int(np.searchsorted(edges, a, side="right") - 1)
        out.append(Plateau(float(run.t[a]), cycle, float((run.y[j] - run.y[i]) /
                                                         (run.t[j] - run.t[i])),
                           float(run.u[i:j].mean())))
    return out


def cycle_friction(points: list[Plateau]) -> list[CycleFriction]:
    """Per cycle, the two directions' lines through its plateaus (cycles with at least two
    speeds in each direction)."""
    out = []
    for c in sorted({p.cycle for p in points}):
        lines, off = [], 0.0
        for sign in (1, -1):
            ps = [p for p in points if p.cycle == c and np.sign(p.speed) == sign]
            if len({round(p.speed, 3) for p in ps}) < 2:
                break
            v, f = np.array([p.speed for p in ps]), np.array([p.force_n for p in ps])
            slope, intercept = np.polyfit(v, f, 1)
            lines += [float(intercept), float(slope)]
            off = max(off, float(np.abs(f - intercept - slope * v).max()))
        if len(lines) == 4:
            out.append(CycleFriction(c, *lines, off))
    return out


def to_markdown(rows: list[CycleFriction]) -> list[str]:
    out = ["| cycle | upward: intercept (N) | upward: slope (N·s/m) | downward: intercept (N) | "
           "downward: slope (N·s/m) | symmetric viscous (N·s/m) | direction-odd viscous "
           "(N·s/m) | largest plateau off its line (N) |", "|---|---|---|---|---|---|---|---|"]
    out += [f"| {r.cycle + 1} | {r.intercept_up:+.2f} | {r.slope_up:.1f} | "
            f"{r.intercept_down:+.2f} | {r.slope_down:.1f} | {r.viscous:.1f} | "
            f"{r.viscous_odd:+.1f} | {r.off_line_n:.2f} |" for r in rows]
    return out
