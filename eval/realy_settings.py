"""The settings of a REALY evaluation: the knobs that trade the official numbers for speed, and
the linear solvers, apart from the alignment that uses them so that the command line reads its
defaults without loading the alignment (``facegeo``'s parser is built for every command)."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

__all__ = ["Settings", "EXACT", "SOLVERS"]

#: Accepted values of ``Settings.solver`` (:mod:`facegeo.eval.realy_solver`).
SOLVERS = ("auto", "cholmod", "superlu")


@dataclass(frozen=True)
class Settings:
    """The knobs that trade the official numbers for speed. The defaults (:data:`EXACT`) are the
    official protocol, with the linear systems solved to 1e-10 relative residual.

    * ``rigid_tolerance``: a regional rigid ICP stops when its mean squared residual changes by
      less than this (scan units squared; official 1e-6);
    * ``rigid_max_updates``: at most this many rigid updates per region (official 100);
    * ``nicp_epsilon_scale``: multiplies the non-rigid ICP's stopping thresholds ``0.5 ** k``
      (official 1);
    * ``nicp_max_steps``: at most this many solves per stiffness stage (None: the official 11
      with keypoints, no limit for the cheek);
    * ``solver_rtol``: relative residual of the factor-preconditioned conjugate gradients of the
      ``superlu`` solver (1e-10 keeps the official numbers);
    * ``factor_reuse``: False makes the ``superlu`` solver factor every system (slower, the same
      numbers to rounding);
    * ``follow_decisions``: False skips following the non-rigid ICP's decisions that round-off could
      turn (:func:`facegeo.eval.realy_error.region_error`): the same numbers, in about a third
      (regions of 600-1,600 vertices) to a half (2,300-6,200) less time, but their reported
      uncertainty counts the final closest points' ties only, a lower bound.

    ``solver`` picks the linear solver (:mod:`facegeo.eval.realy_solver`): ``"cholmod"``,
    ``"superlu"`` or ``"auto"`` (CHOLMOD when CVXOPT is installed). It does not loosen the
    protocol: both give the official numbers to rounding.
    """

    rigid_tolerance: float = 1e-6
    rigid_max_updates: int = 100
    nicp_epsilon_scale: float = 1.0
    nicp_max_steps: int | None = None
    solver_rtol: float = 1e-10
    factor_reuse: bool = True
    solver: str = "auto"
    follow_decisions: bool = True

    #: the fields that keep the official numbers (to rounding) whatever their value
    EXACT_FIELDS = ("solver", "factor_reuse", "follow_decisions")

    def __post_init__(self) -> None:
        if self.solver not in SOLVERS:
            raise ValueError(f"solver must be one of {', '.join(SOLVERS)}, not {self.solver!r}")
        for name in ("rigid_tolerance", "nicp_epsilon_scale", "solver_rtol"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, not {value!r}")
        if self.rigid_max_updates < 0 or (self.nicp_max_steps is not None and self.nicp_max_steps < 1):
            raise ValueError("rigid_max_updates must be >= 0 and nicp_max_steps >= 1")

    def loosened(self) -> dict[str, object]:
        """The fields that differ from the official protocol and change its numbers ({} when exact)."""
        default = Settings()
        return {f.name: getattr(self, f.name) for f in fields(self)
                if f.name not in self.EXACT_FIELDS and getattr(self, f.name) != getattr(default, f.name)}


#: The official protocol (the default everywhere).
EXACT = Settings()
