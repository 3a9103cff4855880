"""The integer decay's width, defined once for the layers that need it.

The fixed-point contract (:mod:`vprsnn_export.export.model`) states the decay as
``V <- trunc0(V (4096 - dv) / 4096)``: a 12-bit fraction, Loihi's. The compiled integer kernel
(:mod:`vprsnn_export.targets.intsim_kernel`) computes the same shift; the constant lives here, in
the core, below both.
"""

from __future__ import annotations

from typing import Final

DECAY_BITS: Final[int] = 12  # Loihi: decays are 12-bit, 4096 = no decay; V <- (V keep) >> DECAY_BITS

__all__ = ["DECAY_BITS"]
