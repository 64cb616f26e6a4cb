"""The mechanism study's result (``mechanism.json``) and its one mapping to and from JSON."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class MechanismResult:
    """Per case its summary (:func:`experiments.studies.mechanism.summary.summarize`: finding
    (iii) with its intervals and Holm-adjusted p, the mechanism's medians), the settings as the
    config names them, the wall time (s; None before the run is timed) and every cell
    (:mod:`experiments.studies.mechanism.cells`, one per case and record, in task order)."""

    cases: dict[str, dict]
    settings: dict
    wall_time_s: float | None = None
    cells: tuple[dict, ...] = ()

    def to_json(self) -> dict:
        return {"cases": self.cases, "settings": self.settings,
                "wall_time_s": self.wall_time_s, "cells": list(self.cells)}

    @classmethod
    def from_json(cls, d: dict) -> MechanismResult:
        return cls(d["cases"], d["settings"], d.get("wall_time_s"), tuple(d.get("cells", ())))
