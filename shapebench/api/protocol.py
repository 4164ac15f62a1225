"""The evaluation protocol: what a method sees at test time and the frame distances are taken in.

Both change results without changing any method or dataset option, so both are part of every
cell key, recorded as run tags and printed in the leaderboard header.

* ``context_normals``: whether a :class:`~shapebench.api.types.Context` carries the normals of its
  points. The paper's protocol gives methods the context *points* only (its appendix: ground-truth
  normals are not accessible at test time), so the default is ``False`` for every method; rows run
  with normals are labelled ``+normals`` and never shown under the paper's row names.
* ``frame``: the scale shapes are measured in. Objects are always normalised to a maximum vertex
  distance of 1 (``unit-radius``), and methods always work in that frame; ``unit-diameter``
  scales completion and ground truth by 1/2 before scoring (squared distances by 1/4), the scale
  of ShapeNet v2's normalisation and of the paper's tables (see docs/metrics.md).

What a cell key promises about its scores (:data:`SCORE_RTOL`): computed twice with the same
number of torch threads on one machine (a rerun, a resumed sweep, ``--force``), a cell gives
bitwise the same scores. Computed with another thread count (``--launcher local -j N`` gives each
worker ``cores // N`` threads, a SLURM job its ``cpus_per_task``) or on another machine, float
reductions are summed in another order and latent optimisation carries the last-bit differences
forward, so the scores agree to a relative :data:`SCORE_RTOL`, not bitwise. Pinning every cell to
one thread count would buy bitwise equality across launchers on one machine only (other CPUs run
other SIMD kernels) at the cost of idle cores, so the contract is the tolerance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from shapebench.api.errors import ConfigError

#: Bump when the meaning of a cell changes for reasons no option shows.
PROTOCOL_VERSION = "2"

#: Frame name -> factor applied to coordinates before scoring, and its description.
FRAMES: dict[str, tuple[float, str]] = {
    "unit-radius": (1.0, "unit-radius frame (centre of mass at the origin, max vertex distance 1)"),
    "unit-diameter": (
        0.5,
        "unit-diameter frame (centre of mass at the origin, max vertex distance 0.5; the scale "
        "of the paper's tables)",
    ),
}
DEFAULT_FRAME = "unit-radius"
#: The frame whose values are comparable with the paper's published figures.
PAPER_FRAME = "unit-diameter"

#: Relative tolerance within which two computations of one cell key agree across launchers,
#: thread counts and machines (see the module docstring). The launcher tests measured 8e-8
#: (IGR, 50 latent-optimisation steps, 1 against 2 threads); the margin covers longer searches.
SCORE_RTOL = 1e-5


def scores_agree(a: float, b: float, rtol: float = SCORE_RTOL) -> bool:
    """Whether two values of one score agree under the cell-key contract (NaN agrees with NaN)."""
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return math.isclose(a, b, rel_tol=rtol, abs_tol=0.0)


@dataclass(frozen=True)
class Protocol:
    context_normals: bool = False
    frame: str = DEFAULT_FRAME

    def __post_init__(self) -> None:
        if self.frame not in FRAMES:
            raise ConfigError(
                f"unknown evaluation frame {self.frame!r}",
                f"use one of: {', '.join(FRAMES)} (--frame)",
            )

    @property
    def scale(self) -> float:
        """Factor applied to every coordinate before metrics see it."""
        return FRAMES[self.frame][0]

    def config(self) -> dict[str, Any]:
        return {
            "version": PROTOCOL_VERSION,
            "context_normals": self.context_normals,
            "frame": self.frame,
        }

    def describe(self) -> str:
        seen = "points and normals" if self.context_normals else "points only"
        return f"contexts carry {seen}; distances in the {FRAMES[self.frame][1]}"


def frame_description(frame: str) -> str:
    return FRAMES[frame][1] if frame in FRAMES else frame
