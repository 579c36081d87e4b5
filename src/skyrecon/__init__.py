"""skyrecon: 3D understanding of cities from drone cameras.

Stereo depth, two-view geometry, structure from motion, multi-view stereo,
occupancy mapping and path planning, with a synthetic city for testing.
Conventions (frames, units, shapes) are documented in DESIGN.md.
"""

__version__ = "0.1.0"

from skyrecon.errors import EstimationError, InputError, SkyreconError
from skyrecon.numba_cache import configure_numba_cache

# Before any kernel module imports Numba: a read-only install caches kernels per user instead.
configure_numba_cache()

__all__ = ["__version__", "SkyreconError", "InputError", "EstimationError"]
