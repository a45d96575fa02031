"""weldpool_core: the ML library of weldpool (teacher, heatmaps, student, metrics).

It knows nothing of HTTP, SQL or queues; every part works from Python and from the CLI.
"""

from weldpool_core.errors import InvalidInputError, WeightsUnavailableError, WeldpoolError

__all__ = ["InvalidInputError", "WeightsUnavailableError", "WeldpoolError"]
