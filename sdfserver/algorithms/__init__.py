"""The registry of distance-field algorithms, by name."""

from __future__ import annotations

from sdfserver.algorithms.base import Algorithm, AlgorithmRun, RegionJob, WorldBuffers
from sdfserver.algorithms.brute import Brute
from sdfserver.algorithms.conservative import Conservative
from sdfserver.algorithms.exact import Exact
from sdfserver.algorithms.fim import Fim
from sdfserver.algorithms.jfa import Jfa
from sdfserver.algorithms.jfa_fim import JfaFim
from sdfserver.errors import InvalidInput
from sdfserver.incoming import short

ALGORITHMS: dict[str, Algorithm] = {a.name: a for a in (Exact(), Brute(), Fim(), Jfa(), Jfa(1), Jfa(2), JfaFim(),
                                                      Conservative())}
DEFAULT_ALGORITHM = "exact"
DEFAULT_LOD_ALGORITHM = "jfa"


def get_algorithm(name: str) -> Algorithm:
    try:
        return ALGORITHMS[name]
    except (KeyError, TypeError):
        raise InvalidInput(
            f"unknown algorithm {short(name)}; choose one of {sorted(ALGORITHMS)}"
        ) from None


__all__ = ["ALGORITHMS", "Algorithm", "AlgorithmRun", "RegionJob", "WorldBuffers", "get_algorithm"]
